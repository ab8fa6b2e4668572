"""Metrics of an extended-scene image against its reflectivity map (``metrics.json`` key ``scene``).

The image is the monopulse image, sum power over (slant range, azimuth) seen from the antenna at
t_ref (``process.py``).  Its ground truth is the scene's map (``scene_image.py``):

* **Road-edge range error** (procedural roads, whose edges are known exactly): the image is summed
  over azimuth bins of ``EDGE_ANGLE_BIN_DEG``; in each bin the true slant range of the edge is that
  of the point where the ray at the bin's mean column azimuth from the antenna at t_ref meets the
  edge line (z = 0), and the measured range is the power peak within +-``EDGE_WINDOW_M`` of it
  (less than half of the narrowest road, so the road's other edge is never taken), refined by a
  parabola through log power.  A bin whose peak falls on the window's edge counts as not found.  Per edge: the error
  along its length (one value per bin), its median, rms and max |error|.
* **Entropy** -sum p ln p with p = P / sum P, and **contrast** std(P) / mean(P), over the image
  pixels inside the map's footprint.
* **SSIM** (``skimage.metrics.structural_similarity``, data range 1) between the image and the
  reference power |a|^2 (normalised map, no speckle) resampled onto the image grid (bilinear, ground
  point of each (range, azimuth) pixel at z = 0), both in dB relative to their maximum, clipped to
  ``SSIM_DYNAMIC_RANGE_DB`` and scaled to [0, 1], over the footprint's bounding box.
"""
from __future__ import annotations

import numpy as np

EDGE_ANGLE_BIN_DEG = 0.5
EDGE_WINDOW_M = 4.0
SSIM_DYNAMIC_RANGE_DB = 40.0


def _ground_of_image(range_m, angle_deg, p_ref):
    """Ground (x, y) of every (range, angle) image pixel, z = 0: two [n_range, n_angle] arrays."""
    rho = np.sqrt(np.maximum(np.asarray(range_m)[:, None] ** 2 - p_ref[2] ** 2, 0.0))
    a = np.radians(np.asarray(angle_deg))[None, :]
    return p_ref[0] + rho * np.sin(a), p_ref[1] + rho * np.cos(a)


def reference_on_image_grid(ref_amp, pixel_spacing_m, center_m, orientation_deg, range_m, angle_deg, p_ref):
    """Reference power |a|^2 at each image pixel (bilinear), NaN outside the map: [n_range, n_angle]."""
    from scipy.ndimage import map_coordinates

    from ..scenario.scene_image import ground_to_local

    ny, nx = ref_amp.shape
    gx, gy = _ground_of_image(range_m, angle_deg, p_ref)
    u, v = ground_to_local(gx, gy, center_m, orientation_deg)
    j = u / pixel_spacing_m + (nx - 1) / 2.0
    i = (ny - 1) / 2.0 - v / pixel_spacing_m
    inside = (i >= -0.5) & (i <= ny - 0.5) & (j >= -0.5) & (j <= nx - 0.5)
    out = map_coordinates(ref_amp.astype(np.float64) ** 2, [i.ravel(), j.ravel()], order=1, mode="nearest")
    out = out.reshape(i.shape)
    out[~inside] = np.nan
    return out


def edge_true_range_m(v0_m, angle_deg_line, ray_angle_deg, p_ref, center_m, orientation_deg, half_extent_u_m):
    """Slant range at which each ray (azimuth from p_ref) meets the edge line v = v0 + u tan(angle).

    NaN where the ray misses the line inside the map (|u| > half_extent_u_m) or meets it behind.
    """
    from ..scenario.scene_image import ground_to_local

    a = np.radians(np.asarray(ray_angle_deg, dtype=np.float64))
    u0, w0 = ground_to_local(p_ref[0], p_ref[1], center_m, orientation_deg)
    u1, w1 = ground_to_local(p_ref[0] + np.sin(a), p_ref[1] + np.cos(a), center_m, orientation_deg)
    eu, ev = u1 - u0, w1 - w0                           # ray direction in local metres per metre
    t = np.tan(np.radians(angle_deg_line))
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = (v0_m + u0 * t - w0) / (ev - eu * t)
    u_hit = u0 + rho * eu
    ok = (rho > 0) & (np.abs(u_hit) <= half_extent_u_m)
    return np.where(ok, np.sqrt(rho ** 2 + p_ref[2] ** 2), np.nan)


def road_edge_errors(image, range_m, angle_deg, p_ref, edges, *, center_m, orientation_deg, half_extent_u_m,
                     angle_bin_deg=EDGE_ANGLE_BIN_DEG, window_m=EDGE_WINDOW_M):
    """Per edge: measured minus true slant range along the edge (module docstring)."""
    image = np.asarray(image, dtype=np.float64)
    range_m = np.asarray(range_m, dtype=np.float64)
    angle_deg = np.asarray(angle_deg, dtype=np.float64)
    dr = float(range_m[1] - range_m[0])
    lo = np.floor(angle_deg.min() / angle_bin_deg) * angle_bin_deg
    bins = np.floor((angle_deg - lo) / angle_bin_deg).astype(np.int64)
    n_bins = int(bins.max()) + 1
    prof = np.zeros((len(range_m), n_bins))
    np.add.at(prof.T, bins, image.T)                    # sum power over each angle bin
    # each bin's azimuth is the mean of its columns' (the bin is summed over them), not its mid-point
    n_in = np.bincount(bins, minlength=n_bins)
    centres = np.where(n_in > 0, np.bincount(bins, weights=angle_deg, minlength=n_bins) / np.maximum(n_in, 1),
                       lo + (np.arange(n_bins) + 0.5) * angle_bin_deg)
    half_w = int(np.ceil(window_m / dr))
    out = {}
    for name, v0, ang in edges:
        truth = edge_true_range_m(v0, ang, centres, p_ref, center_m, orientation_deg, half_extent_u_m)
        along = []
        for b in np.nonzero(np.isfinite(truth))[0]:
            k0 = int(np.rint((truth[b] - range_m[0]) / dr))
            a_, b_ = max(k0 - half_w, 1), min(k0 + half_w, len(range_m) - 2)
            if b_ <= a_:
                continue
            seg = prof[a_:b_ + 1, b]
            if not np.any(seg > 0):
                continue
            k = a_ + int(np.argmax(seg))
            if k in (a_, b_):                           # peak on the window's edge: not found
                continue
            y = np.log(np.maximum(prof[k - 1:k + 2, b], 1e-300))
            den = y[0] - 2 * y[1] + y[2]
            frac = 0.5 * (y[0] - y[2]) / den if den < 0 else 0.0
            along.append((float(centres[b]), float(range_m[k] + frac * dr - truth[b])))
        errs = np.array([e for _, e in along])
        n_cols = int(np.sum(np.isfinite(truth)))
        out[name] = {
            "n_bins": n_cols, "n_found": len(along),
            "median_error_m": float(np.median(errs)) if len(errs) else None,
            "median_abs_error_m": float(np.median(np.abs(errs))) if len(errs) else None,
            "rms_error_m": float(np.sqrt(np.mean(errs ** 2))) if len(errs) else None,
            "max_abs_error_m": float(np.max(np.abs(errs))) if len(errs) else None,
            "along": [[round(a, 4), round(e, 4)] for a, e in along],
        }
    return out


def entropy_contrast(power):
    p = np.asarray(power, dtype=np.float64).ravel()
    total = p.sum()
    if total <= 0:
        return float("nan"), float("nan")
    q = p[p > 0] / total
    return float(-np.sum(q * np.log(q))), float(np.std(p) / np.mean(p))


def _to_unit_db(power, dyn_db):
    peak = np.max(power)
    db = 10.0 * np.log10(np.maximum(power / peak, 10 ** (-dyn_db / 10.0))) if peak > 0 else np.full_like(power, -dyn_db)
    return (db + dyn_db) / dyn_db


def ssim_to_reference(image, reference):
    """SSIM of image vs reference power (NaN = outside the map) over the footprint's bounding box."""
    try:
        from skimage.metrics import structural_similarity
    except ImportError:                       # scikit-image comes with the [test] extra (make install)
        return float("nan")
    inside = np.isfinite(reference)
    rows, cols = np.nonzero(np.any(inside, axis=1))[0], np.nonzero(np.any(inside, axis=0))[0]
    if len(rows) < 7 or len(cols) < 7:
        return float("nan")
    sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    ref = np.where(inside[sl], reference[sl], 0.0)
    img = np.where(inside[sl], np.asarray(image, dtype=np.float64)[sl], 0.0)
    a = _to_unit_db(img, SSIM_DYNAMIC_RANGE_DB)
    b = _to_unit_db(ref, SSIM_DYNAMIC_RANGE_DB)
    return float(structural_similarity(a, b, data_range=1.0))


def scene_metrics(image, range_m, angle_deg, p_ref, scn: dict) -> dict:
    """The ``scene`` block of metrics.json for an image scene (module docstring)."""
    from ..scenario.scene_image import PROCEDURAL, reference_amplitude, road_edges_m

    sc = scn["scene"]
    im = sc["image"]
    ref_amp = reference_amplitude(scn)
    ref = reference_on_image_grid(ref_amp, im["pixel_spacing_m"], sc["center_m"], im["orientation_deg"],
                                  range_m, angle_deg, np.asarray(p_ref, dtype=np.float64))
    inside = np.isfinite(ref)
    img = np.asarray(image, dtype=np.float64)
    ent, con = entropy_contrast(img[inside])
    ref_ent, ref_con = entropy_contrast(ref[inside])
    out = {"entropy": ent, "contrast": con, "ssim": ssim_to_reference(img, ref),
           "reference_entropy": ref_ent, "reference_contrast": ref_con,
           "footprint_pixels": int(inside.sum())}
    if im["file"] in PROCEDURAL:
        half_u = 0.5 * ref_amp.shape[1] * im["pixel_spacing_m"]
        edges = road_edge_errors(img, range_m, angle_deg, np.asarray(p_ref, dtype=np.float64), road_edges_m(),
                                 center_m=sc["center_m"], orientation_deg=im["orientation_deg"],
                                 half_extent_u_m=half_u)
        out["road_edges"] = edges
        errs = [e for v in edges.values() for _, e in v["along"]]
        out["road_edge_median_abs_error_m"] = float(np.median(np.abs(errs))) if errs else None
        out["road_edge_rms_error_m"] = float(np.sqrt(np.mean(np.square(errs)))) if errs else None
        n_all = sum(v["n_bins"] for v in edges.values())
        out["road_edge_found_fraction"] = (sum(v["n_found"] for v in edges.values()) / n_all) if n_all else None
    return _finite(out)


def _finite(obj):
    """NaN and inf to None, so that metrics.json stays strict JSON."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj
