"""The forward-looking scanning monopulse system (Li & Li 2023): INS motion fit (``motion``), exact-geometry
simulator (``simulate``), the chain's stages (``chain``), migration budget (``plan``), evaluation against the
truth (``evaluate``) and the run directory (``process``)."""
