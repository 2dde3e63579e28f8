"""What one sensor's pipeline publishes for a stream of frames, computed in this process: the
estimates (``without_timing``) and the sensor's counters, with fits answered in this process
as a worker answers them (tests/pipeline/pipeline_helpers.py's ``InProcessPool``).

Run as a program (``python tests/native/published.py``) it serves requests on stdin, one a
line: a JSON object ``{"settings": {...}, "frames": "<path of an .npz>"}``; it answers each
with one JSON line ``{"estimates": [...], "counters": {...}}`` (or ``{"error": "..."}``).  The
core or the Python reference runs as ``TACTILED_CORE`` says, so test_published_reference.py
starts one of each and holds their answers equal.
"""

from __future__ import annotations

import json
import sys
import traceback
from pathlib import Path
from typing import Any

import numpy as np

for _where in ("", "pipeline"):  # tests/ (procs) and tests/pipeline (pipeline_helpers)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / _where))

from pipeline_helpers import InProcessPool, play_read  # noqa: E402

from tactiled.fit.fitter import FitOptions, Fitter  # noqa: E402
from tactiled.frames import Frame  # noqa: E402
from tactiled.pipeline.estimate import without_timing  # noqa: E402
from tactiled.pipeline.hub import Hub  # noqa: E402
from tactiled.pipeline import sensor as sensor_module  # noqa: E402
from tactiled.pipeline.sensor import SensorPipeline  # noqa: E402
from tactiled.settings import SensorSettings  # noqa: E402

#: the counters compared: every integer and boolean the sensor reports, less those that
#: depend on the host (its reads, its workers) rather than on the frames
HOST_KEYS = frozenset({"read_backlog_bytes", "read_backlog_peak_bytes", "worker_restarts",
                       "reconnects", "disconnects", "source_errors", "connected", "finished"})
READ = 7  # frames handed over in one call, as a read of several frames is




def save_frames(path: Path, frames: list[Frame]) -> Path:
    """Frames into an ``.npz`` (what a request names): raws of any shape, seq, time, id."""
    arrays = {f"raw{k}": f.raw for k, f in enumerate(frames)}
    meta = np.array([(f.seq, f.device_time_us, f.sensor_id) for f in frames],
                    dtype=np.uint64).reshape(-1, 3)
    np.savez(path, meta=meta, **arrays)
    return path


def load_frames(path: str | Path) -> list[Frame]:
    with np.load(path) as data:
        meta = data["meta"]
        return [Frame(seq=int(s), device_time_us=int(t), raw=data[f"raw{k}"], sensor_id=int(i))
                for k, (s, t, i) in enumerate(meta)]


def publish(frames: list[Frame], settings: dict[str, Any]) -> dict[str, Any]:
    """The estimates ``frames`` make published (timing keys left out) and the counters."""
    hub = Hub()
    seen: list = []
    hub.add_listener(seen.append)
    pool = InProcessPool()
    p = SensorPipeline(SensorSettings(**settings), pool=pool, hub=hub)
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    for i in range(0, len(frames), READ):
        play_read(p, fitter, frames[i:i + READ])
    stats = p.stats().to_json_dict()
    counters = {k: v for k, v in stats.items()
                if k not in HOST_KEYS and (isinstance(v, (bool, int)) or k == "skipped")}
    return {"estimates": [without_timing(e.to_json_dict()) for e in seen
                          if e.kind == "estimate"], "counters": counters}


def main() -> int:
    """Serve requests on stdin until it closes (see the module text).  A read is handed over
    whole (no ``SLICE_S``: where a loaded machine's wall time cuts it is not the frames')."""
    sensor_module.SLICE_S = float("inf")
    for line in sys.stdin:
        try:
            request = json.loads(line)
            out = publish(load_frames(request["frames"]), request["settings"])
        except Exception:  # the test shows it; the server goes on
            out = {"error": traceback.format_exc()}
        sys.stdout.write(json.dumps(out) + "\n")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
