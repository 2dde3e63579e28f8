"""The slip detector (tactiled.fit.slip) on estimates of known motion: no event while the
contact sticks, an onset within a few frames of a slide along the tangential force or of a
fall of the force, none for motion against it or with the stick zone resolved, and the end
when the object sticks again."""

import math

import numpy as np
import pytest

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
    # moving against Q is not slip along it (the stick zone gone within the bound, the margin
    # resolved above 0); a moving centre with a resolved stick zone neither
    backwards = [(5.0 - (0.0025 * (i - 99) ** 2 if i >= 100 else 0.0), 0.97) for i in range(130)]
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

    monkeypatch.setattr(slip, "MARGIN_SIGMA", -1.0)  # the motion's rules alone: lam reaches 1
    both = [onset(scene(s)) for s in range(10)]  # at frame 100, where the margin rule may fire
    monkeypatch.setattr(slip, "COMBINE_Z", math.inf)
    apart = [onset(scene(s)) for s in range(10)]
    assert all(b is not None and 100 <= b and (a is None or b <= a) for b, a in zip(both, apart)), (both, apart)
    assert np.mean([b - 100 for b in both]) < np.mean([(a if a is not None else 112) - 100 for a in apart])
    assert all(onset(scene(s, lam_top=0.95, moves=False)) is None for s in range(10))


def _limit_scene(seed: int, top: float, frames: int = 330, s_lam: float = 0.015):
    """A pull whose tangential force ramps (0.002 N a frame from 0.1 N; 1 N normal, mu 0.5)
    until ``Q / (mu P)`` reaches ``top`` and stays there, the centre still: with ``top`` 1 the
    true onset is frame 200 (the friction at its limit, no motion, no drop); below 1 a hold.
    Each frame: ``(q, lam)`` with Gaussian noise of 3 mN and ``s_lam``."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(frames):
        q = min(0.1 + 0.002 * i, top * 0.5)
        out.append((q + 0.003 * rng.normal(), q / 0.5 + s_lam * rng.normal()))
    return out


def _limit_onset(frames, s_lam: float = 0.015):
    det = SlipDetector()
    for i, (q, lam) in enumerate(frames):
        p, c = estimate(5.0, min(1.0, max(0.0, lam)), q=q, s_lam=s_lam)
        _, ev = det.update(i, p, c, lam)
        if ev and ev.kind == "onset":
            return i
    return None


def test_a_pull_that_stays_put_at_the_friction_limit_is_declared_from_the_margin(monkeypatch):
    """The quasi-static pull: the force stops at mu P, the stick zone gone, nothing moves.  The
    margin to slip pooled over the contact's history (lam against Q/P) reaches 0 within its
    bound: the onset is declared within 5 frames of the truth on every seed; without the margin
    rule (the motion and the force's drop alone) it is never declared.  Grips held at 0.9 and
    0.95 of the limit give no onset."""
    import tactiled.fit.slip as slip

    onsets = [_limit_onset(_limit_scene(s, 1.0)) for s in range(8)]
    assert all(o is not None and abs(o - 200) <= 5 for o in onsets), onsets
    assert all(_limit_onset(_limit_scene(s, top)) is None for s in range(8) for top in (0.9, 0.95))
    monkeypatch.setattr(slip, "MARGIN_SIGMA", -1.0)  # the margin rule off
    assert all(_limit_onset(_limit_scene(s, 1.0)) is None for s in range(4))


def test_an_unresolved_margin_declares_nothing():
    """With a frame's lam known to 0.3 only (a coarse array, a small contact), the pooled
    margin's bound stays over MARGIN_SIGMA through the scene: a hold at 0.95 of the limit gives
    no onset, though its margin is not told from 0."""
    from tactiled.fit.slip import MARGIN_SIGMA

    assert all(_limit_onset(_limit_scene(s, 0.95, s_lam=0.3), s_lam=0.3) is None for s in range(4))
    det = SlipDetector()
    for i, (q, lam) in enumerate(_limit_scene(0, 0.95, s_lam=0.3)):
        p, c = estimate(5.0, min(1.0, max(0.0, lam)), q=q, s_lam=0.3)
        det.update(i, p, c, lam)
    assert det.margin[1] > MARGIN_SIGMA


def test_the_margin_and_its_bound_against_the_truth():
    """The pooled line (lam against Q/P under stick, weighted least squares with an
    intercept) on 300 noisy histories of known mu: the margin's error over its statistical
    sigma is a unit normal (RMS within 15 % of 1, 2-sigma coverage 90-99 %); where every
    frame's lam is biased by BIAS of its sigma, the margin moves by that bias (the line's
    prediction of a constant is the constant), within the floor its sigma keeps; on
    noiseless frames it is exact."""
    from tactiled.fit.slip import BIAS, NEAR, Margin

    rng = np.random.default_rng(3)
    for bias in (0.0, BIAS * 0.05):
        z, err = [], []
        for _ in range(300):
            mu, m = rng.uniform(0.3, 1.0), Margin()
            for q in np.linspace(0.05, 0.9 * mu, 60):
                p, c = estimate(5.0, 0.0, q=q + 0.003 * rng.normal(), s_lam=0.05)
                m.add(p, c, q / mu + bias + 0.05 * rng.normal())
            est, s = m.margin(0.9 * mu, 0.0)
            lam, s_line, _, n = m.line(0.9 * mu, NEAR * 0.9 * mu)
            assert n == m.frames >= 20 and est == pytest.approx(1.0 - lam)
            assert s == pytest.approx(math.hypot(s_line, m.floor)) and m.floor >= BIAS * 0.05 * (1 - 1e-9)
            z.append((est - 0.1 + bias) / s_line)
            err.append(est - 0.1)
        z = np.array(z)
        assert 0.85 < math.sqrt(np.mean(z ** 2)) < 1.15 and 0.90 <= np.mean(np.abs(z) <= 2) <= 0.99
        assert abs(np.mean(err) + bias) < 3 * np.std(err) / math.sqrt(len(err))
    m = Margin()
    for q in (0.2, 0.25, 0.3):
        p, c = estimate(5.0, 0.0, q=q)
        m.add(p, c, q / 0.4)
    assert m.margin(0.38, 0.0)[0] == pytest.approx(0.05, abs=1e-12)


def test_the_margins_sums_are_those_of_its_newest_frames():
    """The margin keeps its sums per bin of Q/P over the newest HISTORY frames (the oldest
    taken out as a new one comes): after 2.6 HISTORY frames of a varied history its line, its
    bound and its floor equal a weighted least squares over those frames computed afresh (the
    weights: the previous frame's variance), the selection at the bin edge."""
    from tactiled.fit.slip import BIN, HISTORY, Margin

    rng = np.random.default_rng(5)
    m, rows, prev = Margin(), [], None
    for i in range(int(2.6 * HISTORY)):
        q = 0.05 + 0.45 * (0.5 + 0.5 * math.sin(i / 300.0)) + 0.003 * rng.normal()
        s_lam = rng.uniform(0.02, 0.08)
        p, c = estimate(5.0, 0.0, q=q, s_lam=s_lam)
        lam = q / 0.6 + s_lam * rng.normal()
        m.add(p, c, lam)
        # lam - k Q/P: Q's sigma 3 mN, ln P's 0.01 at P = 1 N (the estimate's bounds)
        var = s_lam ** 2 + (m._k * 0.003) ** 2 + (m._k * q * 0.01) ** 2
        rows.append((q, lam, 1.0 / (prev if prev is not None else var), s_lam))
        prev = var
    x, y, w, s_w = np.array(rows[-HISTORY:]).T
    at, lo = 0.45, 0.3
    sel = x >= math.ceil(lo / BIN - 1e-9) * BIN
    a = np.stack((np.ones(sel.sum()), x[sel]), axis=1)
    coef = np.linalg.solve(a.T @ (w[sel, None] * a), a.T @ (w[sel] * y[sel]))
    lam, s, k, n = m.line(at, lo)
    assert n == sel.sum() and k == pytest.approx(coef[1], rel=1e-9)
    assert lam == pytest.approx(coef[0] + coef[1] * at, rel=1e-9)
    cov = np.linalg.inv(a.T @ (w[sel, None] * a))
    res = y[sel] - a @ coef
    scale = max(1.0, float(w[sel] @ res ** 2) / (n - 2))
    assert s == pytest.approx(math.sqrt(scale * np.array((1.0, at)) @ cov @ np.array((1.0, at))), rel=1e-6)
    h = (cov @ np.array((1.0, at))) @ (w[sel, None] * a).T  # lam at ``at`` is sum h_i y_i
    assert h.sum() == pytest.approx(1.0)
    from tactiled.fit.slip import BIAS

    b = np.minimum(np.floor(x[sel] / BIN), 1023)
    per_bin = [float(np.sum(h[b == v] * s_w[sel][b == v])) for v in np.unique(b)]
    assert m.floor == pytest.approx(BIAS * np.sum(np.abs(per_bin)), rel=1e-6)


def test_the_limit_scene_stays_put_at_the_friction_limit():
    """The simulator's quasi-static pull (``limit``): Q/(mu P) rises as the ramp until the true
    onset, then Q stays at mu P (lam 1, no kinetic drop) and the centre does not move; a pull
    (``pull``) moves its centre from the onset on."""
    from tactiled.sensors import load_description
    from tactiled.sim.shear import sequence

    desc = load_description("xela_uskin_4x4")
    frames, t = sequence(desc, "limit", np.random.default_rng(2))
    on = int(t["true_onset"])
    q = np.hypot(t["true_fx"], t["true_fy"])
    mu_p = t["true_mu"] * t["true_force"]
    assert 0 < on < len(frames) - 50 and frames.shape == (len(q), 4, 4, 3)
    assert np.allclose(q[on:], mu_p[on:]) and np.all(t["true_lam"][on:] == 1.0) and np.all(t["true_slip"][on:] == 1)
    assert np.all(q[:on] < mu_p[:on]) and np.allclose(t["true_lam"][:on], q[:on] / mu_p[:on])
    assert np.ptp(t["true_x"]) == 0.0 and np.ptp(t["true_y"]) == 0.0
    _, p = sequence(desc, "pull", np.random.default_rng(2), kinetic=1.0)
    assert int(p["true_onset"]) == on and np.hypot(p["true_x"][-1] - p["true_x"][0], p["true_y"][-1] - p["true_y"][0]) > 0.05


def test_one_frame_of_the_force_low_is_no_slip():
    """A kinetic drop persists, one frame's noise does not: a contact near slip whose ``|Q|``
    reads 6.5 of its sigma low on one frame alone (the stick zone gone within the frame's
    bound) declares nothing; the same fall kept from that frame on is an onset on it or the
    next."""
    def onset(kept: bool):
        det = SlipDetector()
        for i in range(200):
            q = 0.3 + 0.002 * min(i, 100) - (6.5 * 0.003 if i == 150 or (kept and i > 150) else 0.0)
            _, ev = det.update(i, *estimate(5.0, 0.95, q=q, s_lam=0.06))
            if ev and ev.kind == "onset":
                return i
        return None

    assert onset(kept=False) is None
    assert onset(kept=True) in (150, 151)


def test_a_grip_held_below_the_limit_levels_off_without_slip():
    """A grip ramped to 0.95 of the friction's limit and held from frame 100 (its force levels
    off there), each frame's ``lam`` 0.95 +/- 0.03 (the stick zone gone within one frame's
    bound, resolved by the frames since the ramp's end pooled), its centre shifted by one
    frame's sigma over 4 frames at the ramp's end: the levelling-off is real and the shift a
    chance of the noise, no slip; the same with ``lam`` at 1 (the stick zone gone) is an onset
    within 20 frames."""
    def onset(seed: int, top: float):
        rng = np.random.default_rng(seed)
        det = SlipDetector()
        for i in range(160):
            q = 0.3 + 0.002 * min(i, 100) + 0.003 * rng.normal()
            lam = 0.5 + (top - 0.5) * min(i, 100) / 100 + 0.03 * rng.normal()
            x = 5.0 + 0.02 * rng.normal() + (0.02 * min(i - 99, 4) / 4 if i >= 100 else 0.0)
            p, c = estimate(x, min(1.0, max(0.0, lam)), q=q, sx=0.02, s_lam=0.03)
            _, ev = det.update(i, p, c, lam)
            if ev and ev.kind == "onset":
                return i
        return None

    assert [onset(s, 0.95) for s in range(6)] == [None] * 6
    assert all(o is not None and 100 <= o <= 120 for o in (onset(s, 1.0) for s in range(6)))
