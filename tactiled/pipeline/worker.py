"""The fit worker process: builds its fitters once, then answers requests over a Connection."""

# Runs in a child started with the ``forkserver`` (or ``spawn``) method, never ``fork``: the
# parent runs an asyncio loop, and forking a process with a running loop and threads is unsafe.
# The protocol is tuples pickled over one duplex ``multiprocessing`` Connection, answered strictly
# in order (which is what lets the parent give every outstanding request a deadline):
#
# - started with its initial specs, it answers ``("ready", pid, warm_up_s, broken)``, where
#   ``broken`` maps a spec whose fitter could not be built to the error (its fits then answer
#   with that error: one sensor's bad model must not keep the worker from serving the others);
# - ``("fit", rid, spec, strain, model, mask, warm, budget_s, kind)`` (``strain`` and ``mask``
#   packed by :func:`tactiled.pipeline.worker_packing.pack_array`) -> ``("result", rid,
#   fit_json_dict | None, compute_s, error | None, warm | None, lin | None)`` (the fitter
#   raising costs one frame, never the worker); ``warm`` is ``(model, params)`` of a converged
#   fit, the next frame's warm start; ``budget_s`` the fit's time budget (``Fitter.fit``);
#   ``kind`` "fit", "fit+lin" (and the fit's :class:`~tactiled.fit.linearize.Linearization`) or
#   "lin" (only the linearisation of the frame at the sent ``warm``: no fit);
# - ``("setup", rid, spec, SensorModel, options)`` -> ``("setup_done", rid, build_s, error)``;
# - ``("ping", rid)`` -> ``("pong", rid)``;
# - ``("memory", rid)`` -> ``("memory", rid, figures)``: where this process's memory is
#   (:func:`tactiled.heapstats.worker_figures`: RSS, malloc and pymalloc books, the fitter's
#   caches, fits so far; ``flat_fields``: each spec's ``FlatField.summary()``), for the soak and
#   for diagnosing growth;
# - ``("stop",)``: exit.
#
# ``spec`` is a small integer naming a (SensorModel, FitOptions arguments) pair the parent
# registered.  Its arguments may carry ``("learned", (path, name, wire_id, fingerprint,
# restore))``: the fitter's flat field is then kept in that file (:mod:`tactiled.pipeline.learned`):
# loaded when the fitter is built if ``restore`` (the parent checked the file belongs to the
# sensor), saved after each of its re-solves and when the worker stops.
# The worker exits when told to, or when the parent's end of the pipe closes (EOF): a daemon
# killed with SIGKILL leaves no orphaned workers behind.

from __future__ import annotations

import os
import signal
import sys
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from tactiled.sensors.model import SensorModel
from tactiled.heap import pin_malloc, settle, trim
from tactiled.pipeline.estimate import plain
from tactiled.pipeline.worker_packing import unpack_array

#: A worker gives malloc's free memory back to the system every this many fits (tactiled.heap
#: .trim: about a minute of steady fitting, a few milliseconds each time).
TRIM_EVERY_FITS = 20000

#: (SensorModel, FitOptions keyword arguments as ``((name, value), ...)``)
Spec = tuple[SensorModel, tuple[tuple[str, Any], ...]]


class _Keeper:
    """Where a fitter's flat field is kept (the spec's ``learned`` argument)."""

    def __init__(self, fitter: Any, args: tuple[Any, ...]) -> None:
        from tactiled.pipeline import learned

        self.fitter = fitter
        self.path = Path(args[0])
        self.owner = learned.Owner(args[1], args[2], args[3])
        self.saved_fits = -1
        if args[4] and fitter.flat is not None:
            try:
                state = learned.load(self.path, self.owner)
                if state is not None:
                    fitter.flat.restore(state)
                    self.saved_fits = fitter.flat.fits
            except (learned.Refused, ValueError, KeyError) as err:
                print(f"tactiled worker {os.getpid()}: learned flat field not applied: {err}",
                      file=sys.stderr, flush=True)

    def save(self) -> None:
        """Write the flat field if it learned something since it was last written and holds
        more fits than the file (another worker may keep the same finger)."""
        from tactiled.pipeline import learned

        flat = self.fitter.flat
        if flat is None or flat.fits <= self.saved_fits or flat.fits == 0:
            return
        try:
            if learned.saved_fits(self.path) > flat.fits:
                return
            learned.save(self.path, self.owner, flat.state())
            self.saved_fits = flat.fits
        except OSError as err:
            print(f"tactiled worker {os.getpid()}: cannot save the learned flat field to "
                  f"{self.path}: {err}", file=sys.stderr, flush=True)


def _build(sensor: SensorModel, options: tuple[tuple[str, Any], ...],
           keepers: dict[int, _Keeper], spec: int) -> Any:
    """The fitter of a spec (and its keeper, when its flat field is kept in a file)."""
    from tactiled.fit.fitter import FitOptions, Fitter

    kwargs = dict(options)
    keep = kwargs.pop("learned", None)
    fitter = Fitter(sensor, FitOptions(**kwargs))
    keepers.pop(spec, None)
    if keep is not None:
        keepers[spec] = _Keeper(fitter, keep)
    return fitter


def _several_lin(fitter: Any, strain: Any, results: list[Any], mask: Any) -> Any:
    """The linearisations of a frame's several contacts, in the order ``contacts_json`` lists
    them (the strongest first), or None when one cannot be tracked."""
    from tactiled.fit.multi import linearize_several, strongest

    first = strongest(results)
    order = [results[first], *(r for i, r in enumerate(results) if i != first)]
    if any(not r.contact or r.params is None or not r.model for r in order):
        return None
    return linearize_several(fitter, strain, [(r.model, r.params) for r in order], mask)


def worker_main(conn: Connection, specs: dict[int, Spec]) -> None:
    """Entry point of a worker process (the ``target`` of its ``Process``)."""
    # Ctrl-C in a terminal signals the whole process group; the parent decides when a worker
    # stops (so in-flight fits can finish), so the worker ignores it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    pin_malloc()  # what a large contact's fit frees goes back to the system (tactiled.heap)
    # Here, not at module level: the parent never needs the fitter.
    import numpy as np

    from tactiled.fit.linearize import linearize
    from tactiled.fit.multi import contacts_json, fit_contacts, linearize_several, warm_of
    from tactiled.fit.warm import SEVERAL

    t0 = time.perf_counter()
    fits = 0
    fitters: dict[int, Any] = {}
    keepers: dict[int, _Keeper] = {}
    broken: dict[int, str] = {}
    for key, (sensor, options) in specs.items():
        try:
            fitters[key] = _build(sensor, options, keepers, key)
        except Exception as err:
            broken[key] = f"{type(err).__name__}: {err}"
    # What start-up left (numpy, scipy, the fitters' tables) is frozen: a full collection in a
    # fit then walks only what fits made since, not 25-40 ms of start-up objects (tactiled.heap).
    settle()
    try:
        conn.send(("ready", os.getpid(), time.perf_counter() - t0, broken))
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return  # the parent is gone
            kind = msg[0]
            if kind == "fit":
                _, rid, spec, strain, model, mask, warm, budget_s, job_kind = msg
                strain, mask = unpack_array(strain), unpack_array(mask)
                t = time.perf_counter()
                follow = lin = out = None
                try:
                    fitter = fitters.get(spec)
                    if fitter is None:
                        raise LookupError(f"no fitter for this sensor (building it failed: "
                                          f"{broken.get(spec, 'unknown spec')})")
                    if job_kind == "lin" and warm[0] == SEVERAL:
                        lin = linearize_several(fitter, strain, list(warm[1]), mask)
                        error = None
                    elif job_kind == "lin":
                        lin = linearize(fitter, strain, warm[0], np.asarray(warm[1]), mask)
                        error = None
                    else:
                        results = fit_contacts(fitter, strain, model, mask=mask, warm=warm,
                                               budget_s=budget_s)
                        out, error = plain(contacts_json(results)), None
                        follow = warm_of(results)
                        if job_kind != "fit+lin":
                            pass
                        elif len(results) > 1:
                            # each contact's, in the order of ``contacts`` (the strongest first)
                            lin = _several_lin(fitter, strain, results, mask)
                        elif results[0].params is not None and results[0].model:
                            lin = linearize(fitter, strain, results[0].model,
                                            np.asarray(results[0].params), mask)
                except Exception as err:  # a fitter bug must cost one frame, not the worker
                    out, error = None, f"{type(err).__name__}: {err}"
                fits += 1
                conn.send(("result", rid, out, time.perf_counter() - t, error, follow, lin))
                if fitter is not None:
                    # the learning this fit made due, after its answer and before the next job
                    try:
                        if fitter.catch_up() and spec in keepers:
                            keepers[spec].save()  # a re-solve: what it learned survives a restart
                    except Exception as err:  # the fits go on with what was learnt before
                        print(f"tactiled worker {os.getpid()}: learning the finger failed: "
                              f"{type(err).__name__}: {err}", file=sys.stderr, flush=True)
                if fits % TRIM_EVERY_FITS == 0:
                    trim()  # after the answer: what malloc keeps free after a burst goes back
            elif kind == "ping":
                conn.send(("pong", msg[1]))
            elif kind == "memory":
                from tactiled.heapstats import worker_figures

                flat = {spec: f.flat.summary() for spec, f in fitters.items() if f.flat is not None}
                conn.send(("memory", msg[1], {**worker_figures(), "fits": fits,
                                              "flat_fields": flat}))
            elif kind == "setup":
                _, rid, spec, sensor, options = msg
                t = time.perf_counter()
                try:
                    fitters[spec] = _build(sensor, options, keepers, spec)
                except Exception as err:  # its fits will then answer with an error
                    fitters.pop(spec, None)
                    broken[spec] = f"{type(err).__name__}: {err}"
                    conn.send(("setup_done", rid, time.perf_counter() - t, broken[spec]))
                    continue
                broken.pop(spec, None)
                conn.send(("setup_done", rid, time.perf_counter() - t, None))
            elif kind == "stop":
                return
    except (BrokenPipeError, ConnectionResetError, EOFError):
        return  # the parent went away while we answered
    finally:
        for keeper in keepers.values():
            keeper.save()
        conn.close()
