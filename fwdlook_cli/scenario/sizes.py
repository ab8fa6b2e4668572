"""Derived sizes of a forward-looking scenario checked against the cube-size limit before anything is allocated."""
from __future__ import annotations

import math

from ..errors import BadInput
from ..limits import MAX_PULSES, check_cube_bytes, gib, limit_source, max_cube_bytes

SCATTERER_BYTES = 128           # scene_sim per scatterer: position, amplitude, visible interval, work lists
EXTENT_SAMPLES = 4097           # antenna positions at which the range extent is estimated


def forward_sizes_check(scn: dict, source: str) -> None:
    """Refuse a forward scenario whose pulse count, target-pulse pairs or echo cube exceed the limit.

    Uses only arithmetic on the keys (and a 4097-sample estimate of the scene's range extent), never
    the arrays it bounds.  Raises BadInput naming the key, the derived size and the limit.
    """
    from ..dsp.geometry import C_MPS

    radar, ant, sc = scn["radar"], scn["antenna"], scn["scene"]
    setting = scn.get("simulation", {}).get("max_cube_bytes", "auto")
    limit, where = max_cube_bytes(setting), limit_source(setting)
    duration_s = abs(ant["scan_stop_deg"] - ant["scan_start_deg"]) / ant["scan_rate_dps"]
    if radar["n_pulses"] == "auto":
        pulses = duration_s * radar["prf_hz"]
        if not math.isfinite(pulses) or pulses > MAX_PULSES:
            raise BadInput(f"{source}: radar.n_pulses = auto: a scan of {duration_s:.4g} s (antenna.scan_rate_dps "
                           f"= {ant['scan_rate_dps']:g}) at radar.prf_hz = {radar['prf_hz']:g} needs {pulses:.3g} "
                           f"pulses; at most {MAX_PULSES:,}")
        m = max(2, int(round(pulses)))
    else:
        m = int(radar["n_pulses"])
    if sc["kind"] == "lattice":
        lat = sc["lattice"]
        n_x = len(range(lat["x_offset"], lat["nx"], lat["x_stride"]))
        n_targets = n_x * lat["ny"]
    elif sc["kind"] == "image":
        from .scene_image import image_scene_extent

        n_targets, box = image_scene_extent(scn)   # the map's pixels above the threshold, their ground box
    else:
        n_targets = len(sc["points_m"] or ())
    # the scene simulator (forward/scene_sim.py) works in bounded chunks: its memory grows with the
    # scatterer count, not with the target-pulse pairs
    scatterer_bytes = float(n_targets) * SCATTERER_BYTES
    if scatterer_bytes > limit:
        raise BadInput(f"{source}: scene: {n_targets:,} scatterers need {gib(scatterer_bytes)} to simulate; "
                       f"over {where} = {gib(limit)}")
    dr = C_MPS / (2.0 * radar["fs_hz"])
    if radar["range_window_m"] == "auto":
        r_min, r_max = _range_extent_estimate_m(scn, m, box if sc["kind"] == "image" else None)
        reach = C_MPS * radar["pulse_width_s"] / 2.0 + 10 * dr
        n_range = (r_max - r_min + 2 * reach) / dr + 1
        key = (f"radar.range_window_m = auto: the scene spans slant ranges {r_min:.6g} to {r_max:.6g} m, "
               f"at radar.fs_hz = {radar['fs_hz']:g}")
    else:
        near, far = radar["range_window_m"]
        n_range = (far - near) / dr + 1
        key = f"radar.range_window_m = [{near:g}, {far:g}] at radar.fs_hz = {radar['fs_hz']:g}"
    check_cube_bytes(source, key, n_range, m, channels=2, setting=setting)
    unambiguous_m = C_MPS / (2.0 * radar["prf_hz"])
    if radar["range_window_m"] == "auto" and r_max > unambiguous_m:
        what = "scene.points_m" if sc["kind"] == "points" else "scene.center_m"
        raise BadInput(f"{source}: {what}: the scene reaches a slant range of {r_max:.6g} m, beyond the "
                       f"unambiguous range c / (2 radar.prf_hz) = {unambiguous_m:.6g} m: its echo would "
                       f"arrive after the next pulse; allowed: targets within {unambiguous_m:.6g} m")


def _range_extent_estimate_m(scn: dict, m: int, box=None):
    """(min, max) slant range from the antenna to the scene over the scan: antenna at up to 4097 of the
    m pulse times; targets as their ground bounding box (max at a corner, min at the clamped point);
    ``box``: an image scene's (x0, x1, y0, y1) (``scene_image.image_scene_extent``)."""
    import numpy as np

    from ..dsp.geometry import platform_state

    radar, sc, plat = scn["radar"], scn["scene"], scn["platform"]
    idx = np.unique(np.linspace(0, m - 1, min(m, EXTENT_SAMPLES)).round().astype(np.int64))
    t = idx / radar["prf_hz"]
    pos, _ = platform_state(t, plat["speed_mps"], plat["accel_mps2"], plat["height_m"])
    if sc["kind"] == "lattice":
        lat = sc["lattice"]
        cx, cy = sc["center_m"]
        half_x, half_y = (lat["nx"] - 1) / 2 * lat["spacing_m"], (lat["ny"] - 1) / 2 * lat["spacing_m"]
        x0, x1, y0, y1 = cx - half_x, cx + half_x, cy - half_y, cy + half_y
    elif box is not None:
        x0, x1, y0, y1 = box
    else:
        pts = np.asarray(sc["points_m"], dtype=np.float64)
        x0, x1, y0, y1 = pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()
    dz2 = pos[:, 2] ** 2
    near_dx = np.clip(pos[:, 0], x0, x1) - pos[:, 0]
    near_dy = np.clip(pos[:, 1], y0, y1) - pos[:, 1]
    far_dx = np.maximum(np.abs(x0 - pos[:, 0]), np.abs(x1 - pos[:, 0]))
    far_dy = np.maximum(np.abs(y0 - pos[:, 1]), np.abs(y1 - pos[:, 1]))
    r_min = float(np.sqrt(near_dx**2 + near_dy**2 + dz2).min())
    r_max = float(np.sqrt(far_dx**2 + far_dy**2 + dz2).max())
    return r_min, r_max
