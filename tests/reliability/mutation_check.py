"""Mutation check of the reliability tests: each test must be able to fail.

Each mutation below is a deliberate defect applied to a *copy* of the repository in a temporary
directory (never to the working tree); the named tests are run there and must fail.  The copy's
packages are imported, not this tree's: ``PYTHONPATH`` points at the copy, this interpreter's
editable finders are told to stand aside (``tactiled_bench.checkout.checkout_env``: without it
scikit-build-core's finder answers ``import tactiled`` from the working tree, and every mutant
would run unmutated code), and the compiled core this tree built is copied into the copy's
``tactiled/`` (the mutations are in Python; the core's ABI is checked on import).  Run from the repository root::

    .venv/bin/python tests/reliability/mutation_check.py            # all (~4 min)
    .venv/bin/python tests/reliability/mutation_check.py M3 M14     # some

A mutation whose target text no longer exists is reported as "not applicable" (the code moved
on): update its text.
"""
import os, shutil, subprocess, sys, tempfile, time
from pathlib import Path
SRC = str(Path(__file__).resolve().parents[2])
DST = tempfile.mkdtemp(prefix="tactiled-mut-") + "/repo"
PY = sys.executable
sys.path.insert(0, os.path.join(SRC, "benchmarks"))
from tactiled_bench.checkout import checkout_env  # noqa: E402
import tactiled._core as _core  # noqa: E402  (this tree's build, copied into each mutant)
ENV = checkout_env(DST)

MUTATIONS = [
 ("M1 decoder accepts frames failing their CRC", "tactiled/frames.py",
  "    if cobs_ok and zlib.crc32(memoryview(data)[:-CRC_LEN]) == crc:", "    if cobs_ok:",
  ["tests/reliability/test_serial_faults.py::test_damaged_stream[bitflip]",
   "tests/reliability/test_decoder_fuzz.py::test_fuzzed_streams_are_counted_and_cut_anywhere"]),
 ("M2 decoder buffer unbounded", "tactiled/frames.py",
  "        if len(self._buf) > MAX_ENCODED_LEN:", "        if False:",
  ["tests/reliability/test_decoder_fuzz.py::test_random_bytes_never_raise",
   "tests/reliability/test_decoder_fuzz.py::test_memory_is_bounded_over_a_long_stream[4]",
   "tests/reliability/test_decoder_fuzz.py::test_time_per_megabyte"]),
 ("M3 unplug not reported", "drivers/tactiled_drivers/serial.py",
  "        self.connected = False\n        self.disconnects += 1", "        self.disconnects += 1",
  ["tests/reliability/test_unplug.py::test_unplug_replug_cycles[10]"]),
 ("M4 port not closed on unplug (fd leak)", "drivers/tactiled_drivers/serial.py",
  "                port.close()", "                self.__dict__.setdefault('_leak', []).append(port)",
  ["tests/reliability/test_unplug.py::test_unplug_replug_cycles[10]"]),
 ("M5 no exclusive lock", "drivers/tactiled_drivers/serial.py",
  'self.url.get_bool("exclusive", True)', 'self.url.get_bool("exclusive", False)',
  ["tests/reliability/test_unplug.py::test_second_process_is_refused_with_a_clear_error"]),
 ("M6 decoder not reset on reconnect", "drivers/tactiled_drivers/serial.py",
  "        self.decoder.reset()", "        pass",
  ["tests/reliability/test_unplug.py::test_unplug_replug_cycles[10]"]),
 ("M7 worker death not noticed (sentinel and EOF)", "tactiled/pipeline/supervision.py",
  '        if w.state in ("starting", "ready", "retiring"):\n            self._lose(w, "died"', '        if False:\n            self._lose(w, "died"',
  ["tests/reliability/test_worker_faults.py::test_sigkilled_worker[3]"], [("tactiled/pipeline/supervision.py", 'self._lose(w, "died", f"connection lost: {str(err) or type(err).__name__}")', 'w.conn = None')]),
 ("M8 hung worker never killed", "tactiled/pipeline/supervision.py",
  "                        if now - w.head_since > head.timeout and not self._starved(w, head, now):",
  "                        if False:",
  ["tests/reliability/test_worker_faults.py::test_hung_worker[2]"]),
 ("M8b fit time budget ignored", "tactiled/fit/fitter.py",
  "            self._deadline is not None and time.perf_counter() > self._deadline)", "            False)",
  ["tests/reliability/test_worker_faults.py::"
   "test_frame_far_outside_the_model_costs_a_budgeted_fit_not_a_worker"]),
 ("M9 a fitter exception kills the worker", "tactiled/pipeline/worker.py",
  "                except Exception as err:  # a fitter bug must cost one frame, not the worker",
  "                except ZeroDivisionError as err:",
  ["tests/reliability/test_worker_faults.py::test_fitter_that_raises_costs_frames_not_workers"]),
 ("M10 stale fit results published", "tactiled/pipeline/sensor.py",
  "            if w.ordinal <= self._last_published:", "            if False:",
  ["tests/reliability/test_serial_faults.py::test_damaged_stream[garbage]",
   "tests/reliability/test_serial_faults.py::test_damaged_stream[mixed]",
   "tests/reliability/test_worker_faults.py::test_sigkilled_worker[3]"]),
 ("M11 superseded frames not counted", "tactiled/pipeline/sensor.py",
  "            if self._waiting is not None:\n                self.superseded += 1", "            if self._waiting is not None:\n                pass",
  ["tests/reliability/test_serial_faults.py::test_damaged_stream[garbage]", "tests/reliability/test_soak.py::test_soak_short"]),
 ("M12 calibration version not checked", "tactiled/io/calibration.py",
  "    if not _is_int(version) or version not in VERSIONS:", "    if not _is_int(version):",
  ["tests/reliability/test_bad_files.py::test_bad_calibration_files_are_refused_before_any_worker_starts",
   "tests/reliability/test_bad_files.py::test_replay_and_record_commands_refuse_bad_files"]),
 ("M13 recording version not checked", "tactiled/io/recording.py",
  "    if version != VERSION:", "    if False:",
  ["tests/reliability/test_bad_files.py::test_replay_and_record_commands_refuse_bad_files"]),
 ("M14 fitter numerics changed (solver tolerance)", "tactiled/fit/fitter.py",
  "    tol: float = 1e-9", "    tol: float = 1e-8",
  ["tests/reliability/test_golden_replay.py"]),
 ("M15 hub leaks every estimate (memory)", "tactiled/pipeline/hub.py",
  "            self._latest_estimate[item.sensor] = item", "            self._latest_estimate[item.sensor] = item\n            self.__dict__.setdefault('_leak', []).append(item)",
  ["tests/reliability/test_soak.py::test_soak_short"]),
 ("M16 the worker answers a NaN (as a fitter bug would)", "tactiled/pipeline/worker.py",
  "                        out, error = plain(contacts_json(results)), None", "                        out, error = dict(plain(contacts_json(results)), rms=float('nan')), None",
  ["tests/reliability/test_worker_faults.py::test_sigkilled_worker[3]"]),
 ("M17 bytes held between reads are dropped", "tactiled/frames.py",
  "        chunks[0] = bytes(self._buf) + chunks[0]", "        chunks[0] = chunks[0]",
  ["tests/reliability/test_serial_faults.py::test_every_split_point_across_reads"]),
 ("M18 a config file that is not valid TOML is read as empty", "tactiled/settings/loading.py",
  "            doc = tomllib.load(fh)", "            doc = {}",
  ["tests/reliability/test_bad_files.py::test_truncated_and_invalid_config_files_are_refused"]),
 ("M19 frames of the wrong shape reach the calibration stage", "tactiled/pipeline/sensor.py",
  "        if frame.raw.shape != self._grid_shape:", "        if False:",
  ["tests/reliability/test_serial_faults.py::test_damaged_stream[length]"]),
 ("M20 the decoder slows down (10 us per chunk)", "tactiled/frames.py",
  '    """Decode one delimiter-free chunk to a Frame, or name the DecoderStats counter to bump."""',
  '    """Decode one delimiter-free chunk to a Frame, or name the DecoderStats counter to bump."""\n    time.sleep(1e-5)',
  ["tests/reliability/test_decoder_fuzz.py::test_time_per_megabyte"]),
 ("M21 the decoder keeps every frame it delivers", "tactiled/frames.py",
  "        self._last_seq[frame.sensor_id] = frame.seq",
  "        self._last_seq[frame.sensor_id] = frame.seq\n        self.__dict__.setdefault('_kept', []).append(frame)",
  ["tests/reliability/test_decoder_fuzz.py::test_sequence_memory_is_bounded_by_the_sensor_id_space[16384]",
   "tests/reliability/test_decoder_fuzz.py::test_memory_is_bounded_over_a_long_stream[4]"]),
 ("M22 a truncated last record is an error", "tactiled/io/recording.py",
  "            if have < length:\n                self._truncate(offset, RECORD_HEADER_SIZE + have, warn)\n                return",
  "            if have < length:\n                raise FrameError('cut')",
  ["tests/reliability/test_bad_files.py::test_replay_of_a_recording_cut_short_replays_the_complete_records"]),
 # The fixes of bugs 1-4: each test that was a strict xfail must fail again without its fix.
 ("M23 (bug 1) the device path is not watched while waiting to retry",
  "drivers/tactiled_drivers/serial.py",
  "            if node is not None and node != self._node_at_attempt:", "            if False:",
  ["tests/reliability/test_unplug.py::test_resume_within_a_second_after_a_long_absence[1.6]",
   "tests/reliability/test_unplug.py::"
   "test_device_plugged_in_after_daemon_start_resumes_within_a_second"]),
 ("M24 (bug 2) a fitter that cannot be built kills the worker", "tactiled/pipeline/worker.py",
  "            fitters[key] = _build(sensor, options, keepers, key)\n        except Exception as err:",
  "            fitters[key] = _build(sensor, options, keepers, key)\n        except KeyError as err:",
  ["tests/pipeline/test_pipeline_workers.py::"
   "test_a_fitter_that_cannot_be_built_costs_its_fits_not_the_worker"]),
 ("M25 (bug 3) the baseline step is not clipped", "tactiled/calibration/zeroing.py",
  "                                MAX_STEP_SIGMAS * self.detector.sigma, True)",
  "                                MAX_STEP_SIGMAS * self.detector.sigma, False)",
  ["tests/reliability/test_worker_faults.py::test_one_glitch_frame_barely_moves_the_baseline[0]"]),
 ("M26 (bug 4) replay does not check the records first", "tactiled/commands/replay.py",
  "            reader.scan()", "            pass",
  ["tests/reliability/test_bad_files.py::test_replay_refuses_a_recording_corrupt_in_the_middle"]),
 ("M27 (bug 6) an oversize tail is rejected before the complete chunks", "tactiled/frames.py",
  "        self._buf = bytearray(chunks.pop())\n",
  "        self._buf = bytearray(chunks.pop())\n        self._check_bound()\n",
  ["tests/reliability/test_decoder_fuzz.py::"
   "test_an_oversize_tail_after_a_good_frame_is_not_a_resync"]),
 ("M28 (bug 9) the port is read only when the event loop reads it",
  "drivers/tactiled_drivers/plumbing/read_thread.py",
  "                if now - reader.last_read < STALL_S:",
  "                if True:",
  ["tests/drivers/plumbing/test_port_reader.py::"
   "test_drains_the_device_while_the_event_loop_is_stuck"]),
 ("M29 the reader thread reads into its ring over bytes not yet taken",
  "drivers/tactiled_drivers/plumbing/port_reader.py",
  "        free = self.limit - (at - self._taken)", "        free = self.limit",
  ["tests/drivers/plumbing/test_port_reader.py::"
   "test_stops_reading_at_its_limit_and_loses_nothing"]),
 ("M30 (bug 10) the service leaves its collector to its thresholds", "tactiled/heap.py",
  "        await asyncio.sleep(period_s)\n        gc.collect()",
  "        await asyncio.sleep(period_s)\n        gc.collect(0)",
  ["tests/reliability/test_heap_policy.py"]),
 ("M31 the start-up heap is not frozen", "tactiled/heap.py",
  "    gc.freeze()\n", "",
  ["tests/reliability/test_heap_policy.py"]),
]

def fresh():
    if os.path.exists(DST):
        shutil.rmtree(DST)
    shutil.copytree(SRC, DST, ignore=shutil.ignore_patterns(
        ".venv", ".git", ".hypothesis", ".mypy_cache", ".ruff_cache", ".pytest_cache",
        "*.egg-info", "build", "_built"))
    shutil.copy2(_core.__file__, os.path.join(DST, "tactiled"))
    probe = subprocess.run([PY, "-c", "import tactiled, tactiled._core as c; print(tactiled.__file__, c.__file__)"],
                           cwd=DST, env=ENV, capture_output=True, text=True)
    if not all(f.startswith(DST) for f in probe.stdout.split()) or probe.returncode:
        sys.exit(f"the copy does not import its own code: {probe.stdout}{probe.stderr}")

only = sys.argv[1:]
results = []
for name, path, old, new, tests, *more in MUTATIONS:
    if only and not any(name.startswith(o + " ") for o in only):
        continue
    fresh()
    p = os.path.join(DST, path)
    s = open(p).read()
    if old not in s:
        results.append((name, "MUTATION NOT APPLICABLE")); print(name, "NOT APPLICABLE", flush=True); continue
    open(p, "w").write(s.replace(old, new, 1))
    for path2, old2, new2 in (more[0] if more else []):
        p2 = os.path.join(DST, path2); s2 = open(p2).read(); assert old2 in s2, old2
        open(p2, "w").write(s2.replace(old2, new2, 1))
    t = time.time()
    r = subprocess.run([PY, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-x", "--timeout", "300", *tests],
                       cwd=DST, env=ENV, capture_output=True, text=True)
    tail = [l for l in r.stdout.splitlines() if l.startswith(("FAILED", "ERROR")) or " passed" in l or " failed" in l][-4:]
    verdict = "caught (tests failed)" if r.returncode != 0 else "NOT CAUGHT"
    results.append((name, verdict, tail, round(time.time() - t)))
    print(name, "->", verdict, round(time.time() - t), "s", tail, flush=True)
shutil.rmtree(os.path.dirname(DST), ignore_errors=True)
caught = sum(1 for r in results if r[1].startswith("caught"))
print(f"{caught} of {len(results)} mutations caught")
sys.exit(0 if caught == len(results) else 1)
