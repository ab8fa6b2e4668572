"""The ISAR chain: stages built from a cube and the processing settings."""
from __future__ import annotations


from ..io.stagefile import StageData
from ..runner import Stage
from .geometry import _truth_line_model
from .n0 import estimate_n0
from .stages import azimuth_compress, range_fft, range_ifft, rcmc
import time

from ..errors import BadInput
from ..scenario.isar import CORRECTIONS


# ----------------------------------------------------------------------------------------------
# The chain
# ----------------------------------------------------------------------------------------------
STAGE_NAMES = ("estimate_n0", "range_fft", "rcmc", "range_ifft", "azimuth_compress")   # every ISAR chain's stages


def build_isar_stages(cube, processing: dict):
    """Source data and stage list for ``processing`` (the resolved ``processing:`` section).

    Stages: [``estimate_n0``] ``range_fft``, ``rcmc``, ``range_ifft``, ``azimuth_compress``.
    ``estimate_n0`` runs for ``keystone2_n0_est`` and for a cube without truth (whose range model then
    comes from the data).  Everything the stages need from the cube's truth is passed as explicit
    parameters (the model dict), never read from the scenario.
    """
    correction = processing["correction"]
    if correction not in CORRECTIONS:
        raise BadInput(f"processing.correction = {correction!r}: allowed: {', '.join(CORRECTIONS)}")
    truth_model = _truth_line_model(cube)
    estimate = correction == "keystone2_n0_est" or truth_model is None
    if (correction == "keystone2_n0" and truth_model is None
            and processing.get("n0_pulses", "auto") == "auto"):
        raise BadInput("processing.correction = keystone2_n0: the cube has no /truth/targets geometry "
                       "(position and velocity) to give n0 (eq. 13); set processing.n0_pulses or use "
                       "keystone2_n0_est")
    model = "estimate" if estimate else truth_model.as_dict()
    src = StageData()
    src.add("slow_time_s", cube.slow_time_s, ("slow_time_s",), "s", "slow time, t = 0 at the first pulse")
    src.add("range_m", cube.range_m, ("range_m",), "m", "slant range")
    src.add("echo", cube.sum, ("slow_time_s", "range_m"), "1", "range-compressed echo (single channel)")
    src.attrs.update({k: float(cube.radar[k]) for k in ("fc_hz", "prf_hz", "fs_hz", "bandwidth_hz")})
    stages = []
    if estimate:
        search = processing.get("n0_search", {})
        stages.append(Stage("estimate_n0", estimate_n0, {
            "half_span_lobes": float(search.get("half_span_lobes", 4.0)),
            "points_per_lobe": int(search.get("points_per_lobe", 6)),
            "passes": int(search.get("passes", 2)),
            "ambiguity": processing.get("ambiguity", "auto"), "keystone": processing.get("keystone", "czt")}))
    n0 = processing.get("n0_pulses", "auto")
    if correction == "keystone2_n0_est":
        n0 = "auto"
    stages += [
        Stage("range_fft", range_fft, {}),
        Stage("rcmc", rcmc, {"correction": correction, "keystone": processing.get("keystone", "czt"),
                             "ambiguity": processing.get("ambiguity", "auto"), "n0_pulses": n0,
                             "model": model}),
        Stage("range_ifft", range_ifft, {}),
        Stage("azimuth_compress", azimuth_compress, {"phase": processing.get("azimuth_phase", "model"),
                                                     "model": model}),
    ]
    return src, stages


def run_isar_stages(cube, processing: dict):
    """Run the stage functions in memory (no files); returns (final StageData, timings in s)."""
    data, stages = build_isar_stages(cube, processing)
    timings = {}
    for st in stages:
        t0 = time.perf_counter()
        data = st.fn(data, **st.params)
        timings[st.name] = time.perf_counter() - t0
    return data, timings
