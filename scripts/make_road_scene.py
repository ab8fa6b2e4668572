#!/usr/bin/env python3
"""Write the procedural road scene (``scene.image.file: procedural:roads``) to files, and its truth.

    python scripts/make_road_scene.py OUT_DIR [--nx 200 --ny 200 --spacing 3 --seed 0]

writes OUT_DIR/road_scene.npy (amplitude, float32, row 0 at the top), OUT_DIR/road_scene.png
(8-bit, amplitude scaled to the brightest pixel) and OUT_DIR/road_edges.json (every road edge as
the line v = v0 + u tan(angle) in local image metres, u right, v up, origin at the image centre).
The map is exactly what ``procedural:roads`` generates inside fwdlook (``scene_image.make_road_scene``),
so a scenario may use either; ``.npy`` keeps it bit for bit, the PNG is quantised to 8 bits.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from fwdlook_cli.scenario.scene_image import ROADS, make_road_scene  # noqa: E402


def main(argv=None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dir")
    ap.add_argument("--nx", type=int, default=200)
    ap.add_argument("--ny", type=int, default=200)
    ap.add_argument("--spacing", type=float, default=3.0, help="pixel spacing (m)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the field texture")
    args = ap.parse_args(argv)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    amp, edges = make_road_scene(args.nx, args.ny, args.spacing, args.seed)
    np.save(out / "road_scene.npy", amp)
    from PIL import Image

    Image.fromarray(np.round(255 * amp / amp.max()).astype(np.uint8), mode="L").save(out / "road_scene.png")
    truth = {"pixel_spacing_m": args.spacing, "size_px": [args.nx, args.ny], "seed": args.seed,
             "roads": list(ROADS),
             "edges": [{"name": n, "v0_m": v0, "angle_deg": a} for n, v0, a in edges]}
    (out / "road_edges.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    print(out / "road_scene.npy")
    return out


if __name__ == "__main__":
    main()
