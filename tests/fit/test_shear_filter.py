"""The shear filter and the slide test (tactiled.fit.shear_filter) on Gaussian estimates of a
known truth: the filter's errors within its bounds along a ramp, the centre sharpened by the
frames under stick, and the slide's scale estimated without bias (its statistic a unit normal
where nothing slides)."""

import math

import numpy as np

from tactiled.fit.shear_filter import ShearFilter, SlideTest

SIG = np.array((0.02, 0.01, 0.015, 0.015, 0.003, 0.003, 0.04, 0.1))
CORR = np.eye(8)
CORR[2, 6] = CORR[6, 2] = -0.4  # a centre correlated with the torsion, as on a coarse patch
CORR[0, 1] = CORR[1, 0] = 0.4
COV = CORR * np.outer(SIG, SIG)
CHOL = np.linalg.cholesky(COV)


def truth(i: int, slide: float = 0.0, start: int = 10 ** 9) -> np.ndarray:
    """A 10 mm, 1 N contact at (5, 5) mm pulled along x at 2 mN a frame; from ``start`` the
    centre moves along x by ``slide (k + 1)^2`` mm on the k-th frame."""
    k = i - start
    return np.array((math.log(10.0), 0.0, 5.0 + (slide * (k + 1) ** 2 if k >= 0 else 0.0), 5.0,
                     0.1 + 0.002 * i, 0.0, 0.0, 0.5))


def test_the_filter_follows_a_ramp_within_its_bounds():
    rng = np.random.default_rng(2)
    z = {2: [], 4: [], 6: []}
    sig_x = []
    for _ in range(5):
        flt = ShearFilter()
        for i in range(300):
            t = truth(i)
            flt.update(t + CHOL @ rng.normal(size=8), COV)
            if i >= 50:
                for k in z:
                    v, s = flt.value(k)
                    z[k].append((v - t[k]) / s)
                sig_x.append(flt.value(2)[1])
    for k, zs in z.items():
        zs = np.array(zs)
        ratio = np.sqrt(np.mean(zs ** 2))
        # the forces' bound is their error's spread; the centre's allows for a slow drift (the
        # walk of the stick hypothesis) that this contact does not make
        assert (0.4 if k == 2 else 0.7) < ratio < 1.3, (k, ratio)
        assert np.mean(np.abs(zs) <= 2) > 0.9, k
    # under stick the frames' centres average: far sharper than one frame's
    assert np.median(sig_x) < 0.35 * SIG[2]


def test_the_slide_scale_is_unbiased_and_its_statistic_a_unit_normal():
    """A slide of known scale from a known frame: the test's estimate of the scale, over many
    runs, scatters about the truth by its own sigma; with no slide, the statistic (the scale
    over its sigma) has mean 0 and spread 1."""
    rng = np.random.default_rng(3)
    for slide in (0.0, 0.002):
        errs = []
        for _ in range(100):
            flt, test = ShearFilter(), SlideTest()
            for i in range(66):
                flt.update(truth(i, slide, start=60) + CHOL @ rng.normal(size=8), COV)
                if i >= 58:  # the tracks from here on (those of earlier starts never tested)
                    test.update(flt, 1.0, 0.0)
            scale, sigma = test.estimate(5, "accelerating", 1.0, 0.0)  # started on frame 60
            errs.append((scale - slide) / sigma)
        errs = np.array(errs)
        assert abs(np.mean(errs)) < 0.25 and 0.8 < np.std(errs) < 1.2, (slide, np.mean(errs), np.std(errs))
    # the slide is seen: the statistic far beyond the noise six frames after its start
    assert test.z > 5.0 and test.template in ("accelerating", "steady")


def test_a_force_that_gives_way_restarts_its_filter():
    """The tangential force falls by 0.1 N (33 of its sigma) in one frame, as static friction
    giving way: the filter sees the jump and follows the new force within its bound at once,
    instead of pulling its old ramp along."""
    rng = np.random.default_rng(5)
    flt = ShearFilter()
    late = []
    for i in range(200):
        t = truth(i)
        if i >= 150:
            t[4] -= 0.1
        flt.update(t + CHOL @ rng.normal(size=8), COV)
        if i >= 151:
            v, s = flt.value(4)
            late.append(abs(v - t[4]) / s)
    assert flt.jumps >= 1
    assert max(late) < 3.5 and np.mean(np.array(late) <= 2) > 0.9


def _innovation_chi2(frames: list[np.ndarray]) -> float:
    """The filter run afresh on ``frames``: the sum of its innovations' chi-square."""
    flt, total = ShearFilter(), 0.0
    for p in frames:
        flt.update(p, COV)
        total += flt.chi2
    return total


def test_the_slide_and_levelling_off_together_equal_a_refit_of_their_scales():
    """The joint statistic of a track (the slide and the force levelling off, both scales >= 0)
    against a brute force that shares nothing with the test's recursion: the filter re-run on
    the frames with a slide ``A (k + 1)^2`` and a levelling-off ``B (k + 1)`` taken out from
    the track's start, the least chi-square of the innovations over a grid of ``A, B >= 0``;
    the statistic is the square root of the fall from ``A = B = 0``."""
    rng = np.random.default_rng(7)
    start, n = 40, 47
    seen = {}
    for slide, level in ((0.002, 0.0015), (0.0, 0.0), (0.001, 0.0)):
        frames = []
        for i in range(n):
            t = truth(i, slide, start)
            if i >= start:
                t[4] -= level * (i - start + 1)
            frames.append(t + CHOL @ rng.normal(size=8))
        flt, test = ShearFilter(), SlideTest()
        for p in frames:
            flt.update(p, COV)
            test.update(flt, 1.0, 0.0)
        got = test.tracks[test.track(n - start, "accelerating")]

        def chi2(a: float, b: float) -> float:
            out = []
            for i, p in enumerate(frames):
                q = p.copy()
                if i >= start:
                    q[2] -= a * (i - start + 1) ** 2
                    q[4] += b * (i - start + 1)
                out.append(q)
            return _innovation_chi2(out)

        base = chi2(0.0, 0.0)
        # the chi-square is quadratic in (A, B): fit it from 6 points, minimise on A, B >= 0
        pts = [(0, 0), (1e-3, 0), (0, 1e-3), (1e-3, 1e-3), (2e-3, 0), (0, 2e-3)]
        rows = [(1, a, b, a * a, a * b, b * b) for a, b in pts]
        c = np.linalg.solve(np.array(rows, float), [chi2(a, b) for a, b in pts])
        h = np.array(((2 * c[3], c[4]), (c[4], 2 * c[5])))
        cands = [(0.0, 0.0), (max(0.0, -c[1] / h[0, 0]), 0.0), (0.0, max(0.0, -c[2] / h[1, 1]))]
        ab = np.linalg.solve(h, -c[1:3])
        if (ab >= 0).all():
            cands.append(tuple(ab))
        least = min(c[0] + c[1] * a + c[2] * b + c[3] * a * a + c[4] * a * b + c[5] * b * b for a, b in cands)
        want = math.sqrt(max(0.0, base - least))
        assert abs(got - want) < 1e-6 * max(1.0, want), (slide, level, got, want)
        seen[slide, level] = got
    # the slide with the levelling-off is seen beyond the slide alone, far beyond the noise
    assert seen[0.002, 0.0015] > seen[0.001, 0.0] > 3.0 > seen[0.0, 0.0]
