"""Extended scenes: a reflectivity map (image file or procedural roads) turned into ground scatterers.

``scene.kind: image`` reads ``scene.image`` (schema in ``config.py``):

* ``file``: a PNG or TIFF (read with Pillow), a ``.npy`` array, an HDF5 dataset written
  ``path.h5:/group/dataset``, or ``procedural:roads`` (:func:`make_road_scene`, generated from the
  keys below, nothing read from disk).  Relative paths are relative to the working directory.
  Colour images are averaged over their colour channels (alpha ignored).
* ``pixel_spacing_m`` (square pixels), ``scene.center_m`` (ground (x, y) of the image centre),
  ``orientation_deg`` (azimuth of the image's "up", from +y towards +x; 0: up is +y, forward).
* ``intensity``: ``amplitude`` (pixel value is the scattering amplitude) or ``power`` (its square
  root is).  Amplitudes are normalised to a maximum of 1 and scaled by ``scene.amplitude``.
* ``threshold``: pixels whose normalised amplitude is below it are dropped (0: keep every non-zero).
* ``speckle``: each pixel gets a phase uniform in [0, 2 pi) from ``numpy.random.default_rng([seed,
  SPECKLE_STREAM])`` with ``seed = noise.seed`` (a stream apart from the noise's own); false: phase 0.

Pixel (i, j) of an (ny, nx) map (row 0 at the top) sits at local (u, v) = ((j - (nx-1)/2) d,
((ny-1)/2 - i) d): u right, v up; the map is then rotated by ``orientation_deg`` and moved to
``center_m``; z = 0.

The procedural scene (``procedural:roads``, also written to PNG/NPY by ``scripts/make_road_scene.py``)
is a speckled field of smooth patches, :data:`ROADS` (dark strips with one bright line at each
edge, drawn with exact sub-pixel weights so that each edge's ridge lies on its true line), and a few
bright point reflectors.  Road edges are known exactly in local (u, v) metres: :func:`road_edges_m`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import BadInput

SPECKLE_STREAM = 0x5EC
PROCEDURAL = ("procedural:roads",)

# Roads of the procedural scene, in local image metres (v forward, u right, centre (0, 0)): each a
# straight strip of width_m whose centre line passes through (0, v0_m) at angle_deg from the u axis
# (0: across the scene, perpendicular to the flight path; positive turns towards +v).
ROADS = (
    {"name": "road_a", "v0_m": 96.0, "angle_deg": 0.0, "width_m": 15.0},
    {"name": "road_b", "v0_m": -105.0, "angle_deg": 8.0, "width_m": 12.0},
)
POINT_REFLECTORS_UV_M = ((-150.0, 20.0), (120.0, -30.0), (30.0, 190.0), (-60.0, -200.0))


# ----------------------------------------------------------------------------------------------
# Procedural roads
# ----------------------------------------------------------------------------------------------
def road_edges_m(roads=ROADS):
    """Each road edge as (name, v0_m, angle_deg): the line v = v0 + u tan(angle), local metres."""
    out = []
    for rd in roads:
        off = 0.5 * rd["width_m"] / np.cos(np.radians(rd["angle_deg"]))  # v offset of an edge at fixed u
        out.append((f"{rd['name']}_near", rd["v0_m"] - off, rd["angle_deg"]))
        out.append((f"{rd['name']}_far", rd["v0_m"] + off, rd["angle_deg"]))
    return out


def _line_distance_m(u, v, v0, angle_deg):
    """Signed perpendicular distance of (u, v) from the line v = v0 + u tan(angle)."""
    a = np.radians(angle_deg)
    return (v - v0) * np.cos(a) - u * np.sin(a)


def make_road_scene(nx=200, ny=200, pixel_spacing_m=3.0, seed=0, *, field_amplitude=1.0, road_amplitude=0.05,
                    edge_amplitude=4.0, point_amplitude=10.0):
    """Procedural reflectivity (amplitude, float32 [ny, nx], row 0 at the top, +v) and its road edges.

    Field: smooth patches (Gaussian-filtered noise, amplitude 0.5 to 1.5 x ``field_amplitude``);
    roads: ``road_amplitude`` inside the strip; edges: a ridge of ``edge_amplitude`` with a triangular
    sub-pixel profile of one pixel half-width centred on the exact edge line (its power centroid
    across the edge is the line); points: single bright pixels at :data:`POINT_REFLECTORS_UV_M`.
    Returns (amplitude_map, edges) with edges from :func:`road_edges_m`.
    """
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    d = float(pixel_spacing_m)
    u = (np.arange(nx) - (nx - 1) / 2.0) * d
    v = ((ny - 1) / 2.0 - np.arange(ny)) * d
    uu, vv = np.meshgrid(u, v)
    patches = gaussian_filter(rng.standard_normal((ny, nx)), sigma=max(1.0, 20.0 / d))
    patches /= max(np.max(np.abs(patches)), 1e-12)
    amp = field_amplitude * (1.0 + 0.5 * patches)
    for rd in ROADS:
        dist = _line_distance_m(uu, vv, rd["v0_m"], rd["angle_deg"])
        amp = np.where(np.abs(dist) < 0.5 * rd["width_m"], road_amplitude, amp)
    for _name, v0, ang in road_edges_m():
        dist = _line_distance_m(uu, vv, v0, ang)
        w = np.clip(1.0 - np.abs(dist) / d, 0.0, None)          # triangle: centroid on the line
        amp = amp * (1.0 - w) + edge_amplitude * w
    for pu, pv in POINT_REFLECTORS_UV_M:
        j = int(round(pu / d + (nx - 1) / 2.0))
        i = int(round((ny - 1) / 2.0 - pv / d))
        if 0 <= i < ny and 0 <= j < nx:
            amp[i, j] = point_amplitude
    return amp.astype(np.float32), road_edges_m()


# ----------------------------------------------------------------------------------------------
# Reading a map
# ----------------------------------------------------------------------------------------------
def _split_h5(spec: str):
    for ext in (".h5:", ".hdf5:", ".hdf:"):
        i = spec.lower().find(ext)
        if i >= 0:
            return spec[:i + len(ext) - 1], spec[i + len(ext):]
    return spec, None


def scenario_input_files(scn: dict) -> list[str]:
    """The files a resolved scenario reads besides itself: the scene's map (``scene.image.file``, the
    HDF5 file of ``path.h5:/dataset``) and a measured antenna pattern (``antenna.pattern_file``), so that
    no command writes its output over them (io/outputs.py refuses an input as an output, ``--overwrite``
    or not)."""
    files = []
    scene, ant = scn.get("scene") or {}, scn.get("antenna") or {}
    spec = (scene.get("image") or {}).get("file") if scene.get("kind") == "image" else None
    if spec and spec not in PROCEDURAL:
        files.append(_split_h5(str(spec))[0])
    if ant.get("pattern") == "table" and ant.get("pattern_file"):
        files.append(str(ant["pattern_file"]))
    return files


def read_map(spec: str, *, where: str = "scene.image.file", image_cfg: dict | None = None) -> np.ndarray:
    """The 2-D float64 map named by ``spec`` (see module docstring); BadInput on any problem."""
    if spec in PROCEDURAL:
        cfg = image_cfg or {}
        nx, ny = cfg.get("size_px", [200, 200])
        amp, _ = make_road_scene(int(nx), int(ny), float(cfg.get("pixel_spacing_m", 3.0)),
                                 int(cfg.get("procedural_seed", 0)))
        return amp.astype(np.float64)
    path_s, dataset = _split_h5(spec)
    path = Path(path_s)
    allowed = "a PNG, TIFF, .npy, path.h5:/dataset or procedural:roads"
    if not path.is_file():
        what = "a folder, not an image file" if path.is_dir() else "image file not found"
        raise BadInput(f"{path}: {where}: {what}; allowed: {allowed}")
    suffix = path.suffix.lower()
    try:
        if dataset is not None or suffix in (".h5", ".hdf5", ".hdf"):
            import h5py

            if not dataset:
                raise BadInput(f"{path}: {where}: an HDF5 file needs a dataset: write {path}:/name")
            with h5py.File(path, "r") as f:
                if dataset not in f or not isinstance(f[dataset], h5py.Dataset):
                    raise BadInput(f"{path}: {where}: no dataset {dataset!r} in the file")
                arr = np.asarray(f[dataset][()])
        elif suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
        elif suffix in (".png", ".tif", ".tiff"):
            from PIL import Image

            with Image.open(path) as im:
                im.load()
                if im.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
                    arr = np.asarray(im, dtype=np.float64)
                else:
                    rgb = im.convert("RGBA" if "A" in im.getbands() else "RGB") if im.mode not in ("L", "LA") else im
                    arr = np.asarray(rgb, dtype=np.float64)
                    if arr.ndim == 3:
                        bands = rgb.getbands()
                        arr = arr[..., [i for i, b in enumerate(bands) if b != "A"]].mean(axis=2)
        else:
            raise BadInput(f"{path}: {where}: unknown image type {suffix or '(none)'!r}; allowed: {allowed}")
    except BadInput:
        raise
    except Exception as exc:  # noqa: BLE001  (any reader failure is the file's fault)
        raise BadInput(f"{path}: {where}: unreadable image ({exc.__class__.__name__}: "
                       f"{' '.join(str(exc).split())[:80]})") from None
    arr = np.asarray(arr)
    shape = tuple(arr.shape)
    while arr.ndim > 2 and 1 in arr.shape:   # length-1 axes beyond two (a [1, ny, nx] stack, a [ny, nx, 1] band);
        arr = np.squeeze(arr, axis=arr.shape.index(1))     # a 1 x n map is a map (squeezing it had refused it)
    if np.iscomplexobj(arr):
        arr = np.abs(arr)
    if arr.ndim != 2 or arr.size == 0 or min(arr.shape) == 0:
        raise BadInput(f"{path}: {where}: image of shape {shape}; allowed: a non-empty 2-D image")
    if not np.issubdtype(arr.dtype, np.number) and arr.dtype != bool:
        raise BadInput(f"{path}: {where}: image of type {arr.dtype}; allowed: numbers")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise BadInput(f"{path}: {where}: pixel values must be finite and >= 0")
    if not np.any(arr > 0):
        raise BadInput(f"{path}: {where}: every pixel is zero; allowed: an image with some reflectivity")
    return arr


def pixel_ground_xy_m(shape, pixel_spacing_m, center_m, orientation_deg):
    """Ground (x, y) of every pixel centre of an (ny, nx) map: two float64 [ny, nx] arrays."""
    ny, nx = shape
    u = (np.arange(nx) - (nx - 1) / 2.0) * pixel_spacing_m
    v = ((ny - 1) / 2.0 - np.arange(ny)) * pixel_spacing_m
    uu, vv = np.meshgrid(u, v)
    return local_to_ground(uu, vv, center_m, orientation_deg)


def local_to_ground(u, v, center_m, orientation_deg):
    """Local image metres (u right, v up) to ground (x, y): rotate "up" to azimuth orientation_deg."""
    a = np.radians(orientation_deg)
    x = center_m[0] + u * np.cos(a) + v * np.sin(a)
    y = center_m[1] - u * np.sin(a) + v * np.cos(a)
    return x, y


def ground_to_local(x, y, center_m, orientation_deg):
    a = np.radians(orientation_deg)
    dx, dy = np.asarray(x) - center_m[0], np.asarray(y) - center_m[1]
    return dx * np.cos(a) - dy * np.sin(a), dx * np.sin(a) + dy * np.cos(a)


_LAST_MAP: list = []     # [(key, map)]: the last map read, as every check of a command asks for it again


def reference_amplitude(scn: dict) -> np.ndarray:
    """Normalised (max 1) real amplitude map of an image scene, before threshold and speckle (read-only).

    The last one read is kept, by the file's path, size and modification time and the settings that
    shape it: a command's checks, its size check and its simulation ask for the same map, and a large
    map had been read and converted four times before the size check could refuse it."""
    im = scn["scene"]["image"]
    spec = str(im["file"])
    try:
        st = Path(_split_h5(spec)[0]).stat() if spec not in PROCEDURAL else None
    except OSError:
        st = None
    key = (spec, None if st is None else (st.st_size, st.st_mtime_ns), im["intensity"],
           repr(sorted((k, v) for k, v in im.items() if k in ("size_px", "pixel_spacing_m", "procedural_seed"))))
    if _LAST_MAP and _LAST_MAP[0][0] == key and (st is not None or spec in PROCEDURAL):
        return _LAST_MAP[0][1]
    _LAST_MAP.clear()                     # (not held while the next one is read)
    arr = read_map(spec, image_cfg=im)
    if im["intensity"] == "power":
        np.sqrt(arr, out=arr)
    arr /= np.max(arr)
    arr.flags.writeable = False
    _LAST_MAP.append((key, arr))
    return arr


def _kept_pixels(scn: dict):
    """(the normalised map, the mask of its scatterers: non-zero pixels at or above ``threshold``)."""
    im = scn["scene"]["image"]
    amp = reference_amplitude(scn)
    keep = (amp > 0) & (amp >= im["threshold"])
    if not keep.any():
        raise BadInput(f"scene.image.threshold = {im['threshold']:g}: drops every pixel of {im['file']}; "
                       f"allowed: below the brightest normalised amplitude (1)")
    return amp, keep


def image_scene_extent(scn: dict):
    """(number of scatterers, (x0, x1, y0, y1) their ground bounding box) of an image scene, from the map
    alone (no per-pixel coordinates: the size check's arithmetic): the kept pixels' index box, whose
    four corners bound them on the ground (the pixel grid is an affine image of its indices)."""
    sc, im = scn["scene"], scn["scene"]["image"]
    amp, keep = _kept_pixels(scn)
    rows, cols = np.flatnonzero(keep.any(axis=1)), np.flatnonzero(keep.any(axis=0))
    ny, nx = amp.shape
    u = (np.array([cols[0], cols[-1]]) - (nx - 1) / 2.0) * im["pixel_spacing_m"]
    v = ((ny - 1) / 2.0 - np.array([rows[0], rows[-1]])) * im["pixel_spacing_m"]
    x, y = local_to_ground(u[None, :], v[:, None], sc["center_m"], im["orientation_deg"])
    return int(np.count_nonzero(keep)), (float(x.min()), float(x.max()), float(y.min()), float(y.max()))


def image_scene_points(scn: dict):
    """(points [n, 2] ground x, y; complex amplitudes [n]) of an image scene (module docstring)."""
    sc = scn["scene"]
    im = sc["image"]
    amp, keep = _kept_pixels(scn)
    x, y = pixel_ground_xy_m(amp.shape, im["pixel_spacing_m"], sc["center_m"], im["orientation_deg"])
    a = float(sc["amplitude"]) * amp[keep]
    if im["speckle"]:
        rng = np.random.default_rng([int(scn["noise"]["seed"]), SPECKLE_STREAM])
        phase = rng.uniform(0.0, 2.0 * np.pi, size=amp.shape)[keep]   # drawn over the whole map
        a = a * np.exp(1j * phase)
    return np.column_stack([x[keep], y[keep]]), a


def check_image_scene(scn: dict, source: str) -> None:
    """Cross-field checks of ``scene.kind: image`` (the map is read here, so errors come at load time)."""
    sc = scn["scene"]
    im = sc["image"]
    if im["file"] is None:
        raise BadInput(f"{source}: scene.image.file: required when scene.kind is image; allowed: "
                       f"a PNG, TIFF, .npy, path.h5:/dataset or procedural:roads")
    if isinstance(sc["amplitude"], list):
        raise BadInput(f"{source}: scene.amplitude: a list; allowed: one number when scene.kind is image "
                       f"(the pixels give the amplitudes)")
    try:
        arr = read_map(im["file"], image_cfg=im)
    except BadInput as exc:
        raise BadInput(f"{source}: {exc}") from None
    extent = max(arr.shape) * im["pixel_spacing_m"]
    if extent > 100_000.0:
        raise BadInput(f"{source}: scene.image.pixel_spacing_m = {im['pixel_spacing_m']:g}: the "
                       f"{arr.shape[1]} x {arr.shape[0]} image would span {extent / 1e3:.0f} km; allowed: "
                       f"a scene up to 100 km across")
