"""What an acquisition run plays and what it saw: the devices and the scene whose clock they keep,
the estimates kept (flat, so the collector's work stays the daemon's), the truth of any frame
by its seq, and each contact frame's answer (its own fit, a justified reuse, superseded) with
the estimates' errors against the truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactiled.physics.contact import Contact
from tactiled.sensors import DEFAULT_NAME
from tactiled.sim import DEFAULT_HYSTERESIS, HAND_PARTS, AnyScene, MultiScene, named_scene


FINGERS = ("thumb", "index", "middle")
#: A phantom contact estimate this soon (s) after the truth last touched is a lift-off published
#: late (Answers.phantom_after_release): the simulated rubber's hysteresis time constant.
LATE_RELEASE_S = DEFAULT_HYSTERESIS.tau_s
#: The scene that runs six devices at once: a hand's five fingertips and its palm, each its
#: own simulator playing its part of one grasp (``tactiled.sim.HAND_PARTS``).
HAND = "hand"


@dataclass(frozen=True)
class Device:
    """One simulated device of a run: the daemon's sensor name, the scene it plays and the
    sensor description of its array."""

    name: str
    scene: str
    description: str = DEFAULT_NAME


def devices(scene: str) -> tuple[Device, ...]:
    """The devices of a run of ``scene``: three fingers playing it, or the hand's six parts."""
    if scene == HAND:
        return tuple(Device(part, sc, desc) for part, (sc, desc) in HAND_PARTS.items())
    return tuple(Device(name, scene) for name in FINGERS)


def known_scene(scene: str) -> bool:
    """Whether ``scene`` names a run: a built-in scene or the hand."""
    from tactiled.sim import SCENES

    return scene == HAND or scene in SCENES


def timeline(scene: str) -> AnyScene:
    """The scene whose clock every device of a run keeps: the named one; for the hand, every
    track of its parts together, whose touching spans are each part's (every part is pressed
    when the grasp closes and released when it opens), so it says whether a frame's part
    touches, not with what."""
    if scene != HAND:
        return named_scene(scene)
    return MultiScene([tr for sc, _ in HAND_PARTS.values() for tr in named_scene(sc).tracks], HAND)
PARAMS = ("r1_mm", "angle_deg", "force_n", "x_mm", "y_mm")
INDENTORS = ("cylinder", "sphere", "edge")


# --------------------------------------------------------------------------------------------
# What one run saw, and what it means


@dataclass(frozen=True)
class Seen:
    """One estimate published in the measured window: the finger's index, the frame's seq,
    the gate's decision, frame -> estimate latency (ms) and the fit line's keys that the
    summary reads (``SLIM_KEYS``).  (Made after the run; a baseline's result, pickled by its
    own code, comes back as one too.)"""

    finger: int
    seq: int
    gate: str
    latency_ms: float
    fit: dict[str, Any]
    #: contacts the estimate reported: the length of its ``contacts`` list when it has one,
    #: else 1 or 0 (its top-level contact); None: not counted
    contacts: int | None = None

    @classmethod
    def from_record(cls, record: tuple[Any, ...]) -> Seen:
        """The Seen of a record as the run's listener keeps it: ``(finger, seq, gate,
        latency_ms, slim(fit)[, contacts])``."""
        return cls(*record[:4], dict(zip(SLIM_KEYS, record[4])), *record[5:6])


#: The keys of an estimate's fit line that :func:`summarise` reads.
SLIM_KEYS = ("contact", "fit_ms", "message", *PARAMS)


def contacts_of(item: Any) -> int:
    """How many contacts an estimate reports: its ``contacts`` list's length (on the estimate
    or in its fit line) when it carries one, else its top-level contact (1 or 0)."""
    listed = getattr(item, "contacts", None)
    if listed is None:
        listed = item.fit.get("contacts")
    if listed is not None:
        return len(listed)
    return int(bool(item.fit.get("contact")))


def slim(fit: dict[str, Any]) -> tuple[Any, ...]:
    """The values of ``SLIM_KEYS`` in a fit line: the flat part the summary needs.  What a
    run keeps of its ~60 000 estimates must not weigh on the daemon it measures: a tuple of
    numbers and strings is one the garbage collector stops tracking, while the whole fit
    lines (nested dicts) made every full collection walk them all (up to 69 ms each, a stall of
    the loop that showed as the run's p99 latency)."""
    return tuple(fit.get(k) for k in SLIM_KEYS)


@dataclass
class RunResult:
    """One run of the sweep: counters before and after the measured window, what the
    listener saw in it, CPU seconds used, the simulators' own counts."""

    workers: int
    before: dict[str, Any]
    after: dict[str, Any]
    elapsed: float  # s
    seen: list[Seen]
    cpu_s: dict[str, float | None]  # "daemon", "workers", "simulators": CPU seconds in the window
    device: list[tuple[int, int, int] | None] = field(default_factory=list)
    tares: int = 0  # tares it took to zero every sensor on untouched frames
    label: str = ""  # whose code ran ("" alone; "this tree" / "baseline REV" side by side)
    #: the daemon's sensor names, in device order (a baseline's result: the three fingers)
    parts: tuple[str, ...] = FINGERS
    #: the measured window in windows of about a second: (seconds, the daemon's main process's
    #: CPU seconds, frames every sensor handled)
    windows: list[tuple[float, float, int]] = field(default_factory=list)
    #: the duration (s) of every garbage collection the daemon's process ran in the measured
    #: window, of any generation
    gc_s: list[float] = field(default_factory=list)

    @property
    def who(self) -> str:
        """The run's name in the tables: its worker count, and whose code with a baseline."""
        return f"{self.label}, {self.workers}" if self.label else str(self.workers)


def indentor(c: Contact) -> str:
    """What the truth is: ``sphere`` (r1 = r2), ``edge`` (r1 < 1 mm), ``cylinder`` or
    ``general``."""
    if math.isclose(c.r1, c.r2, rel_tol=1e-9):
        return "sphere"
    if math.isinf(c.r2):
        return "edge" if c.r1 < 1.0 else "cylinder"
    return "general"


def scene_truth(scene: str, rate: float) -> Callable[[int], Contact | None]:
    """``truth(seq)``: the contact of the simulated finger's frame ``seq`` (a looping scene at
    ``rate`` Hz, as ``tactiled simulate`` plays it: seq = tick index)."""
    sc = timeline(scene)
    per_pass = max(1, round(sc.duration * rate))
    cache: dict[int, Contact | None] = {}

    def truth(seq: int) -> Contact | None:
        k = seq % per_pass
        if k not in cache:
            cache[k] = sc.contact_at(k / rate)
        return cache[k]

    return truth


def scene_detectable(scene: str, rate: float) -> Callable[[int, int], bool]:
    """``detectable(finger, seq)``: whether the truth of device ``finger``'s frame ``seq``
    (its own scene and array, :func:`devices`) is above the detection limit: its noise-free
    strain's matched-filter statistic at least the daemon's enter threshold (its defaults:
    noise sigma 0.0005, 1e-4 false contacts a frame, two frames averaged;
    docs/concepts/calibration.md, "Contact detection").  Below it no detector can see the
    touch without more false contacts: a press's first and a release's last few
    hundredths of a newton."""
    from tactiled.calibration.detection import ContactDetector
    from tactiled.settings import SensorSettings
    from tactiled.sensors import load_description
    from tactiled.sim import FingerSimulator

    d = SensorSettings()
    cache: dict[int, np.ndarray] = {}
    devs = devices(scene)

    def limits(finger: int) -> np.ndarray:
        dev = devs[finger]
        sensor = load_description(dev.description).sensor_model()
        sim = FingerSimulator(sensor, scene=dev.scene, rate_hz=rate, noise=0.0, drift=None,
                              hysteresis=None, loop=False)
        det = ContactDetector(d.noise_sigma, sensor=sensor, false_rate=d.false_rate,
                              average=d.detector_average)
        out = np.zeros(sim.ticks_per_pass, dtype=bool)
        for k in range(out.size):
            tick = sim.step()
            out[k] = bool(tick.contacts) and det.statistic(tick.physics) >= det.enter_threshold
        return out

    def detectable(finger: int, seq: int) -> bool:
        if finger not in cache:
            cache[finger] = limits(finger)
        above = cache[finger]
        return bool(above[seq % above.size])

    return detectable


def tare_window(scene: str, rate: float) -> tuple[int, int] | None:
    """Ticks ``[lo, hi)`` into a pass of ``scene`` at which to tare: early in its first idle of
    0.4 s or more, so the zeroer's baseline (formed over its 0.25 s settling time, and moved
    afterwards only while nothing touches) starts from an unloaded finger; None if the scene
    has no such idle."""
    sc = timeline(scene)
    if isinstance(sc, MultiScene):
        spans = sc.idle_spans()
    else:
        spans = [(sc.segment_start(i), sc.segment_start(i) + seg.duration)
                 for i, seg in enumerate(sc.segments) if seg.kind == "idle"]
    for t0, t1 in spans:
        if t1 - t0 >= 0.4:
            return round((t0 + 0.02) * rate), round((t0 + 0.1) * rate)
    return None


def abs_error(key: str, est: float, c: Contact) -> float | None:
    """|estimate - truth| in reporting units: % for radius (r1) and force, degrees (folded into
    [0, 90]; None for a sphere, which has no orientation), micrometres for x and y."""
    if key == "r1_mm":
        return 100.0 * abs(est / c.r1 - 1.0)
    if key == "force_n":
        return 100.0 * abs(est / c.force - 1.0)
    if key == "angle_deg":
        if indentor(c) == "sphere":
            return None
        return abs((est - c.psi_deg + 90.0) % 180.0 - 90.0)
    return 1000.0 * abs(est - (c.x0 if key == "x_mm" else c.y0))


@dataclass
class Accuracy:
    """Absolute errors of streamed estimates against the truth, per parameter; ``withheld``
    counts estimates in contact whose value was null (the fitter said why)."""

    estimates: int = 0
    errors: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in PARAMS})
    withheld: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PARAMS, 0))

    def add(self, fit: dict[str, Any], c: Contact) -> None:
        self.estimates += 1
        for k in PARAMS:
            v = fit.get(k)
            if v is None:
                if not (k == "angle_deg" and indentor(c) == "sphere"):
                    self.withheld[k] += 1
                continue
            e = abs_error(k, float(v), c)
            if e is not None:
                self.errors[k].append(e)

    def cell(self, k: str) -> str:
        errs = self.errors[k]
        fmt = "{:.2f}" if k in ("angle_deg", "force_n") else "{:.1f}"
        text = fmt.format(float(np.median(errs))) if errs else "-"
        w = self.withheld[k]
        if w and self.estimates:
            text += f" ({100.0 * w / self.estimates:.0f} % withheld)"
        return text


@dataclass
class Answers:
    """How a run's contact frames were answered (all fingers together)."""

    frames: int = 0  # every frame the pipelines handled in the window
    contact: int = 0  # frames the detector called contact (answered or not)
    own_fit: int = 0  # answered by a fit of their own
    reused: int = 0  # answered by the last fit, the chi-square test finding them unchanged
    #: ... of which the tracker could only predict (their frame was not measured: a fit was
    #: late), from the pipelines' counters; not a justified reuse
    predicted: int = 0
    superseded: int = 0  # replaced in the slot by a newer frame before a worker took them
    unanswered: int = 0  # stale fit results dropped, fits lost, fitter errors
    touching: int = 0  # estimates of frames whose truth touches
    missed: int = 0  # ... published as no contact (too light at touch-down / lift-off)
    #: ... of those, frames whose truth is above the detection limit (scene_detectable), and
    #: of these the ones published as no contact
    touching_detectable: int = 0
    missed_detectable: int = 0
    phantom: int = 0  # estimates in contact whose truth does not touch
    #: ... of which the truth touched within LATE_RELEASE_S before: a lift-off published late
    #: (the simulated rubber's hysteresis residual holds the detector on until the daemon's
    #: learner has found it and its compensator takes it out: docs/concepts/calibration.md)
    phantom_after_release: int = 0
    latency_contact: list[float] = field(default_factory=list)  # ms, fit + reuse
    latency_fit: list[float] = field(default_factory=list)  # ms, own fits only
    contacts_reported: int = 0  # contacts the estimates reported (a list's length, or 0/1)
    several: int = 0  # estimates that reported more than one contact
    fit_ms: list[float] = field(default_factory=list)  # the fitter's own time per fit, ms
    kept: int = 0  # auto fits that kept the previous frame's model (one model fitted)
    accuracy: dict[str, Accuracy] = field(default_factory=dict)  # by indentor, and "all"

    def share(self, n: int) -> str:
        return f"{100.0 * n / self.contact:.1f} %" if self.contact else "-"


def counter_delta(after: dict[str, Any], before: dict[str, Any], key: str, sub: str | None = None) -> int:
    if sub:
        return int(after[key][sub]) - int(before[key][sub])
    return int(after[key]) - int(before[key])


def summarise(result: RunResult, truth: Callable[[int], Contact | None] | None,
              only: str | None = None, accuracy: bool = True, late_ticks: int = 0,
              detectable: Callable[[int, int], bool] | None = None) -> Answers:
    """The shares, latencies and accuracy of one run (of its sensor ``only``, else of all).
    Published answers come from the estimates the listener saw in the window; frames never
    answered (superseded, stale, lost) from the pipelines' counters over the same window.
    ``accuracy=False``: compare with ``truth`` only whether a frame touches (the truth says
    when, not what).  ``late_ticks``: a phantom whose truth touched within that many ticks
    before is also counted ``phantom_after_release``.  ``detectable`` (:func:`scene_detectable`):
    the touching frames above the detection limit, and their misses, are counted apart."""
    a = Answers()
    acc: dict[str, Accuracy] = {"all": Accuracy()}
    index = None if only is None else result.parts.index(only)
    for s in result.seen:
        if index is not None and s.finger != index:
            continue
        fit = s.fit
        if s.contacts is not None:
            a.contacts_reported += s.contacts
            a.several += s.contacts > 1
        in_contact = bool(fit.get("contact"))
        if s.gate == "fit":
            a.own_fit += 1
            a.latency_fit.append(s.latency_ms)
            a.latency_contact.append(s.latency_ms)
            if fit.get("fit_ms") is not None:
                a.fit_ms.append(float(fit["fit_ms"]))
            if str(fit.get("message", "")).startswith("model ") and "kept from the previous" in str(fit.get("message")):
                a.kept += 1
        elif s.gate == "unchanged":
            a.reused += 1
            a.latency_contact.append(s.latency_ms)
        if truth is None:
            continue
        c = truth(s.seq)
        if c is None:
            a.phantom += in_contact
            a.phantom_after_release += in_contact and any(
                truth(s.seq - j) is not None for j in range(1, late_ticks + 1))
            continue
        a.touching += 1
        above = detectable is not None and detectable(s.finger, s.seq)
        a.touching_detectable += above
        if not in_contact:
            a.missed += 1
            a.missed_detectable += above
            continue
        if not accuracy:
            continue
        for key in ("all", indentor(c), "own fits" if s.gate == "fit" else "reuses"):
            acc.setdefault(key, Accuracy()).add(fit, c)
    a.accuracy = acc
    for name in (result.parts if only is None else (only,)):
        af, bf = result.after["sensors"][name], result.before["sensors"][name]
        a.frames += counter_delta(af, bf, "frames")
        a.superseded += counter_delta(af, bf, "superseded")
        a.predicted += counter_delta(af, bf, "predicted") if "predicted" in af else 0
        a.unanswered += (counter_delta(af, bf, "stale_dropped") + counter_delta(af, bf, "fit_failed")
                         + counter_delta(af, bf, "fit_errors"))
    a.contact = a.own_fit + a.reused + a.superseded + a.unanswered
    return a
