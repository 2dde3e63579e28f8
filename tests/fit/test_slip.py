"""The slip detector (tactiled.fit.slip) on estimates of known motion: no event while the
contact sticks, an onset within a few frames of a slide along the tangential force or of a
fall of the force, none for motion against it or with the stick zone resolved, and the end
when the object sticks again."""

import math

import numpy as np

from tactiled.fit.slip import END_FRAMES, REST_FRAMES, SlipDetector


def estimate(x: float, lam: float, q: float = 0.5, sx: float = 0.01, s_q: float = 0.003,
             s_lam: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """A frame's estimate in the shear fit's order: a 10 mm, 1 N contact at ``(x, 0)`` mm,
    ``Q = (q, 0)`` N, with independent bounds."""
    params = np.array((math.log(10.0), 0.0, x, 0.0, q, 0.0, 0.0, lam))
    cov = np.diag(np.array((0.01, 0.01, sx, sx, s_q, s_q, 0.01, s_lam)) ** 2)
    return params, cov


def _feed(det, frames):
    events = []
    for i, (x, lam) in enumerate(frames):
        _, ev = det.update(i, *estimate(x, lam))
        if ev:
            events.append((ev.kind, ev.frame))
    return events


def test_slip_detector_on_known_motion():
    rng = np.random.default_rng(0)
    # stick: the centre scatters with its own sigma, the stick zone nearly gone: no event
    still = [(5.0 + 0.01 * rng.normal(), 0.97) for _ in range(400)]
    assert _feed(SlipDetector(), still) == []
    # the centre starts moving along Q at frame 100 (0.5 g): onset within a few frames
    moving = [(5.0 + 0.01 * rng.normal() + (0.0025 * (i - 99) ** 2 if i >= 100 else 0.0), 0.97 if i < 100 else 1.0)
              for i in range(130)]
    events = _feed(SlipDetector(), moving)
    assert events and events[0][0] == "onset" and 100 <= events[0][1] <= 105
    # moving against Q is not slip along it; a moving centre with a resolved stick zone neither
    backwards = [(5.0 - (0.0025 * (i - 99) ** 2 if i >= 100 else 0.0), 1.0) for i in range(130)]
    assert _feed(SlipDetector(), backwards) == []
    stuck = [(5.0 + (0.0025 * (i - 99) ** 2 if i >= 100 else 0.0), 0.5) for i in range(130)]
    assert _feed(SlipDetector(), stuck) == []


def test_slip_detector_on_a_force_drop():
    """Static friction giving way: |Q| falls by many sigma while the stick zone is gone."""
    det = SlipDetector()
    events = []
    for i in range(60):
        _, ev = det.update(i, *estimate(5.0, 0.99, q=0.5 if i < 40 else 0.4))
        if ev:
            events.append((ev.kind, ev.frame))
    assert events == [("onset", 40)]
    # the same drop with a resolved stick zone (an unloading, not a slip) is no event
    det = SlipDetector()
    assert not any(det.update(i, *estimate(5.0, 0.5, q=0.5 if i < 40 else 0.4))[1] for i in range(60))


def test_slip_ends_when_the_object_sticks_again():
    """After an onset: a stick zone seen while the centre still moves is no end; the centre at
    rest with the stick zone resolved ends the slip within REST_FRAMES + END_FRAMES frames; a
    second slide of the same contact is declared again."""
    rng = np.random.default_rng(1)
    det = SlipDetector()
    events = []
    x = 5.0
    for i in range(300):
        if 100 <= i < 150:
            x += 0.002 * (i - 99)  # sliding from frame 100, ever faster
        if i >= 220:
            x += 0.002 * (i - 219)  # and again from frame 220
        lam = 0.97 if i < 100 or i >= 220 else (0.5 if 120 <= i < 130 or i >= 150 else 1.0)
        _, ev = det.update(i, *estimate(x + 0.01 * rng.normal(), lam))
        if ev:
            events.append((ev.kind, ev.frame))
    assert [k for k, _ in events] == ["onset", "end", "onset"]
    assert 100 <= events[0][1] <= 105
    assert 150 <= events[1][1] <= 150 + REST_FRAMES + END_FRAMES
    assert 220 <= events[2][1] <= 226


def _onset(frames, det=None):
    det = det or SlipDetector()
    for i, (x, q, lam) in enumerate(frames):
        _, ev = det.update(i, *estimate(x, lam, q=q, sx=0.02, s_lam=0.02))
        if ev and ev.kind == "onset":
            return i
    return None


def test_the_force_levelling_off_at_the_friction_limit_declares_sooner(monkeypatch):
    """A pull whose force stops rising at frame 100 while the centre starts to move (slowly:
    2.5 um (k + 1)^2 against 20 um a frame): with the friction mobilised, the onset comes no
    later, and on average sooner, than from the motion alone; the force levelling off at the
    friction's limit with the centre still is no slip."""
    import tactiled.fit.slip as slip

    def scene(seed, moves=True):
        rng = np.random.default_rng(seed)
        out = []
        for i in range(112):
            q = 0.3 + 0.002 * min(i, 100)
            lam = 0.5 + 0.47 * min(i, 100) / 100
            x = 5.0 + (0.0025 * (i - 99) ** 2 if moves and i >= 100 else 0.0)
            out.append((x + 0.02 * rng.normal(), q + 0.003 * rng.normal(), min(1.0, lam + 0.02 * rng.normal())))
        return out

    both = [_onset(scene(s)) for s in range(8)]
    monkeypatch.setattr(slip, "CONFIRM_Z", math.inf)
    motion = [_onset(scene(s)) for s in range(8)]
    monkeypatch.undo()
    assert all(b is not None and 100 <= b <= m for b, m in zip(both, motion)), (both, motion)
    assert np.mean(both) < np.mean(motion)
    assert all(_onset(scene(s, moves=False)) is None for s in range(8))


def test_the_slide_and_the_levelling_off_add_up_where_the_stick_zone_is_gone(monkeypatch):
    """A pull whose force stops rising at frame 100 while the centre starts to move (2.5 um
    (k + 1)^2 against 40 um a frame, a noisy array): the slide and the levelling-off together
    declare the onset no later, and on average sooner, than without that rule; a grip held at
    0.95 of the friction's limit (its stick zone resolved: lam 0.95 +/- 0.02) levels off the
    same way and is no slip, its centre still."""
    import tactiled.fit.slip as slip

    def scene(seed, lam_top=1.0, moves=True):
        rng = np.random.default_rng(seed)
        out = []
        for i in range(112):
            q = 0.3 + 0.002 * min(i, 100)
            lam = lam_top * (0.5 + 0.5 * min(i, 100) / 100)
            x = 5.0 + (0.0025 * (i - 99) ** 2 if moves and i >= 100 else 0.0)
            out.append((x + 0.04 * rng.normal(), q + 0.003 * rng.normal(), lam + 0.02 * rng.normal()))
        return out

    def onset(frames):
        det = SlipDetector()
        for i, (x, q, lam) in enumerate(frames):
            p, c = estimate(x, min(1.0, max(0.0, lam)), q=q, sx=0.04, s_lam=0.02)
            _, ev = det.update(i, p, c, lam)
            if ev and ev.kind == "onset":
                return i
        return None

    both = [onset(scene(s)) for s in range(10)]
    monkeypatch.setattr(slip, "COMBINE_Z", math.inf)
    apart = [onset(scene(s)) for s in range(10)]
    monkeypatch.undo()
    assert all(b is not None and 100 <= b and (a is None or b <= a) for b, a in zip(both, apart)), (both, apart)
    assert np.mean([b - 100 for b in both]) < np.mean([(a if a is not None else 112) - 100 for a in apart])
    assert all(onset(scene(s, lam_top=0.95, moves=False)) is None for s in range(10))
