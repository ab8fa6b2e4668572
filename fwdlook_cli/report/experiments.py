"""The reproduction's experiments as data: the papers' claims (each with its source), the Fig. 5/6 panels
(scenario, preset, overrides), the ISAR scenarios.  ``reproduce.py`` runs them, ``render.py`` renders them."""
from __future__ import annotations

from pathlib import Path


REPO = Path(__file__).resolve().parents[2]
SCENARIOS = REPO / "scenarios"
CONFIGS = REPO / "configs"
SWEEPS = CONFIGS / "sweeps"

# ----------------------------------------------------------------------------------------------
# The papers' own claims: the ONLY hand-typed numbers in the reproduction.
# Li & Li (2023), "Decimation keystone algorithm for forward-looking monopulse imaging on platforms
# with uniformly accelerated motion", Front. Sig. Proc. 2:1074053, Section 4.1 and Figures 5-7.
# ----------------------------------------------------------------------------------------------
PAPER_CLAIMS = {
    "sec4.1": {
        "F_0deg": {"value": 12, "source": "Sec. 4.1 (Fig. 5 text)",
                   "quote": "Doppler ambiguity number of the target at theta = 0 deg is F = 12"},
        "F_10deg": {"value": 11, "source": "Sec. 4.1 (Fig. 5 text)",
                    "quote": "Doppler ambiguity number of the target at theta = 10 deg is F_theta = 11"},
        "residual_velocity_mps": {"value": 20.8, "source": "Sec. 4.1, eq. (19)",
                                  "quote": "Delta v = c F_R / (2 f_c cos phi_0) = 20.8 m/s"},
        "residual_velocity_q_mps": {"value": 0.8, "source": "Sec. 4.1, eq. (20)",
                                    "quote": "Delta v' = Delta v / Q = 0.8 m/s"},
        "q": {"value": 25, "source": "Sec. 4.1 (Fig. 5B)", "quote": "The decimating factor is Q = 25"},
        "ambiguity_change_q_10deg": {"value": 4, "source": "Sec. 4.1 (Fig. 5B text)",
                                     "quote": "the Doppler number difference for the point targets at "
                                              "theta = 10 deg is 4"},
    },
    # expect: "accurate" (the paper says the targets are placed right) or "error" (it says the range
    # error is apparent); the verdict column tests that against half a range resolution cell.
    "panels": {
        "5A": {"figure": "Fig. 5A", "expect": "error",
               "claim": "traditional keystone, a = 0: residual velocity from the ambiguity change; range "
                        "displacement roughly proportional to azimuth"},
        "5B": {"figure": "Fig. 5B", "expect": "accurate",
               "claim": "decimation keystone (Q = 25), a = 0: targets located accurately"},
        "6A": {"figure": "Fig. 6A", "expect": "error",
               "claim": "traditional keystone, a = 10: range positioning error apparent (ambiguity change "
                        "and range curvature)"},
        "6B": {"figure": "Fig. 6B", "expect": "error",
               "claim": "traditional keystone, a = 50: range positioning error apparent"},
        "6C": {"figure": "Fig. 6C", "expect": "accurate",
               "claim": "decimation without curvature compensation, a = 10: range curvature not apparent"},
        "6D": {"figure": "Fig. 6D", "expect": "error",
               "claim": "decimation without curvature compensation, a = 50: apparent range curvatures"},
        "6E": {"figure": "Fig. 6E", "expect": "accurate",
               "claim": "decimation with curvature compensation, a = 10: works well"},
        "6F": {"figure": "Fig. 6F", "expect": "accurate",
               "claim": "decimation with curvature compensation, a = 50: acceleration's influence on the "
                        "envelopes eliminated"},
    },
    # Fig. 7: range profile of the target at azimuth distance -300 m, ground range 1700 m (a = 50),
    # interpolated five times.  displacement_m: the paper's "about 3 m" and "invisible" (0).
    "fig7": {
        "target_xy_m": {"value": (-300.0, 1700.0), "source": "Sec. 4.1 (Fig. 7 text)"},
        "interpolation": {"value": 5, "source": "Sec. 4.1 (Fig. 7 text)"},
        "6B": {"curve": "Fig. 7A red: traditional", "displacement_m": 3.0, "displacement_text": "about 3 m",
               "islr_db": -9.93, "source": "Sec. 4.1, Fig. 7A"},
        "6F": {"curve": "Fig. 7A/7B blue: decimation with curvature compensation", "displacement_m": 0.0,
               "displacement_text": "invisible", "islr_db": -14.65, "source": "Sec. 4.1, Fig. 7A"},
        "6D": {"curve": "Fig. 7B red: decimation without curvature compensation", "displacement_m": 3.0,
               "displacement_text": "3 m", "islr_db": -14.34, "source": "Sec. 4.1, Fig. 7B"},
    },
}

# The paper's Fig. 5/6 panels: (scenario file, processing preset, extra overrides).  Traditional uses
# the preset as Sec. 3.1 describes it (keystone plus eq. 12 curvature compensation).
PANELS = {
    "5A": ("paper_fig5_a0.yaml", "traditional.yaml", []),
    "5B": ("paper_fig5_a0.yaml", "decimation.yaml", []),
    "6A": ("paper_fig6_a10.yaml", "traditional.yaml", []),
    "6B": ("paper_fig6_a50.yaml", "traditional.yaml", []),
    "6C": ("paper_fig6_a10.yaml", "decimation.yaml", ["processing.range_curvature=false"]),
    "6D": ("paper_fig6_a50.yaml", "decimation.yaml", ["processing.range_curvature=false"]),
    "6E": ("paper_fig6_a10.yaml", "decimation.yaml", []),
    "6F": ("paper_fig6_a50.yaml", "decimation.yaml", []),
}
QUICK_PANELS = ("6B", "6D", "6F")
ISAR_SCENARIOS = ("isar_theta3.yaml", "isar_theta5.yaml")
