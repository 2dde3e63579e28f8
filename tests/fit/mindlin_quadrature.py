"""An independent simulation of 3-axis readings: the half-space's displacement under a Hertz
pressure, a Cattaneo-Mindlin tangential traction and a torsion, by direct numerical quadrature.

Nothing of tactiled's shear physics is used (not tactiled.physics.halfspace, traction, threeaxis,
hertz or quadrature_rules): the Boussinesq and Cerruti kernels are written here again from
K. L. Johnson, Contact Mechanics (1985), eqs. 3.19 and 3.86 (z positive into the cover); the
contact ellipse of a sphere on the array (flat, or a cylinder of the description's radius) is
solved here from Johnson's eqs. 4.36-4.39 with scipy's complete elliptic integrals; the
tractions are integrated in polar coordinates of the ellipse, ``rho = sin t`` (which takes the
square-root edge of every traction into a smooth integrand: ``sqrt(1 - rho^2) = cos t``), by
Gauss-Legendre in ``t`` and the trapezoid rule in the angle (spectral for a periodic integrand).
The stick zone's term is integrated on its own ellipse (radius ``c``), so its edge is smooth
too. Only the description's constants (layout, depth, modulus, Poisson ratio, compliance,
gains) come from tactiled.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq
from scipy.special import ellipe, ellipk


def kernels(dx: np.ndarray, dy: np.ndarray, z: float, g: float, nu: float) -> np.ndarray:
    """Displacement per newton, ``[i, j, ...]``: along axis i (x, y, z) for a surface point force
    along axis j, at horizontal offsets ``(dx, dy)`` and depth ``z`` (Johnson 3.19, 3.86)."""
    r = np.sqrt(dx * dx + dy * dy + z * z)
    k = 1.0 - 2.0 * nu
    pre = 1.0 / (4.0 * math.pi * g)
    out = np.empty((3, 3) + np.shape(dx))
    for j, (s, t) in enumerate(((dx, dy), (dy, dx))):  # force along x, then along y
        # Cerruti, force along axis s (t is the other horizontal offset)
        along = pre * (1.0 / r + s * s / r ** 3 + k * (1.0 / (r + z) - s * s / (r * (r + z) ** 2)))
        across = pre * (s * t / r ** 3 - k * s * t / (r * (r + z) ** 2))
        out[j, j] = along
        out[1 - j, j] = across
        out[2, j] = pre * (s * z / r ** 3 + k * s / (r * (r + z)))
    # Boussinesq
    for i, s in enumerate((dx, dy)):
        out[i, 2] = pre * (s * z / r ** 3 - k * s / (r * (r + z)))
    out[2, 2] = pre * (z * z / r ** 3 + 2.0 * (1.0 - nu) / r)
    return out


def sphere_ellipse(r_mm: float, force: float, finger_radius: float, compliance: float
                   ) -> tuple[float, float]:
    """Semi-axes ``(a, b)`` (mm, ``a`` along x) of a rigid sphere pressed with ``force`` N on a
    cylinder of radius ``finger_radius`` (its axis along x; inf: flat), cover compliance
    ``(1 - nu^2)/E`` (Johnson 4.36-4.39: ``B/A = ((a/b)^2 E(e) - K(e)) / (K(e) - E(e))``,
    ``a^3 = 3 F k (K - E) / (2 pi e^2 A_x)``)."""
    ax = 0.5 / r_mm  # half the relative curvature along x (the cylinder's axis)
    by = 0.5 * (1.0 / r_mm + (0.0 if math.isinf(finger_radius) else 1.0 / finger_radius))
    if by - ax < 1e-12 * ax:
        a = (3.0 * force * compliance * r_mm / 4.0) ** (1.0 / 3.0)
        return a, a

    def ratio(m: float) -> float:
        k, e = ellipk(m), ellipe(m)
        return (e / (1.0 - m) - k) / (k - e) - by / ax

    m = brentq(ratio, 1e-12, 1.0 - 1e-12, xtol=1e-15, rtol=1e-14)
    a = (3.0 * force * compliance * (ellipk(m) - ellipe(m)) / (2.0 * math.pi * m * ax)) ** (1.0 / 3.0)
    return a, a * math.sqrt(1.0 - m)


class MindlinQuadrature:
    """Readings (x, y, z per taxel) of a 3-axis description, computed by direct quadrature."""

    def __init__(self, desc, nodes: int = 32) -> None:
        self.desc = desc
        self.depth = desc.taxel_depth_mm
        self.nu = desc.cover_poisson
        self.g = desc.modulus_n_mm2 / (2.0 * (1.0 + self.nu))
        sm = desc.sensor_model()
        self.finger = sm.geometry.finger_radius
        self.compliance = sm.material.compliance
        gx, gy = np.meshgrid(np.arange(desc.rows) * desc.pitch_x_mm,
                             np.arange(desc.cols) * desc.pitch_y_mm, indexing="ij")
        self.px, self.py = gx.ravel(), gy.ravel()
        self.gain = np.asarray(desc.axis_gain, float)
        self.noise = np.asarray(desc.axis_noise, float)
        self.nodes = nodes

    def _rule(self, a: float, b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, phi)`` nodes and weights on ``[0, pi/2] x [0, 2 pi)``: enough nodes that the
        kernel's peak (width ~ the depth) under the largest contact is resolved."""
        n_t = max(self.nodes, int(6 * a / self.depth) + 1)
        n_p = 2 * n_t
        t, wt = np.polynomial.legendre.leggauss(n_t)
        t, wt = (t + 1.0) * math.pi / 4.0, wt * math.pi / 4.0
        phi = np.arange(n_p) * (2.0 * math.pi / n_p)
        wp = np.full(n_p, 2.0 * math.pi / n_p)
        tt, pp = np.meshgrid(t, phi, indexing="ij")
        ww = np.outer(wt, wp)
        return tt.ravel(), pp.ravel(), ww.ravel(), np.array((a, b))

    def _sum(self, x0: float, y0: float, ox: np.ndarray, oy: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Displacement ``(points, 3)`` of point forces ``f`` ``(3, nodes)`` at ``(x0 + ox, y0 + oy)``."""
        out = np.empty((self.px.size, 3))
        for start in range(0, self.px.size, 16):
            sl = slice(start, start + 16)
            dx = self.px[sl, None] - (x0 + ox)[None, :]
            dy = self.py[sl, None] - (y0 + oy)[None, :]
            k = kernels(dx, dy, self.depth, self.g, self.nu)  # (3, 3, p, n)
            out[sl] = np.einsum("ijpn,jn->pi", k, f)
        return out

    def displacement(self, r_mm: float, force: float, x0: float, y0: float, fx: float, fy: float,
                     torque: float, lam: float) -> np.ndarray:
        """Displacement (mm) ``(points, 3)`` at every taxel, row-major."""
        a, b = sphere_ellipse(r_mm, force, self.finger, self.compliance)
        t, phi, w, _ = self._rule(a, b)
        s, c = np.sin(t), np.cos(t)
        # the ellipse's points: (a rho cos phi, b rho sin phi), rho = sin t; dA = a b rho drho dphi
        ox, oy = a * s * np.cos(phi), b * s * np.sin(phi)
        area = a * b * s * c * w  # dA in (t, phi): a b sin t cos t dt dphi
        f = np.zeros((3, w.size))
        # Hertz pressure 3P/(2 pi a b) sqrt(1 - rho^2), along +z
        hertz = 3.0 / (2.0 * math.pi * a * b) * c * area
        f[2] = force * hertz
        q = math.hypot(fx, fy)
        out = self._sum(x0, y0, ox, oy, f)
        if q > 0.0 or torque != 0.0:
            g = np.zeros((3, w.size))
            if q > 0.0 and lam < 1e-9:
                stick = area / c / (2.0 * math.pi * a * b)  # Q/(2 pi a b sqrt(1 - rho^2)) per N
                g[0], g[1] = fx * stick, fy * stick
            elif q > 0.0:
                g[0], g[1] = fx / lam * hertz, fy / lam * hertz
            if torque != 0.0:
                kk = 3.0 * torque / (2.0 * math.pi * a * b * (a * a + b * b))
                g[0] += -kk * oy * area / c
                g[1] += kk * ox * area / c
            out = out + self._sum(x0, y0, ox, oy, g)
        if q > 0.0 and lam >= 1e-9 and lam < 1.0:
            # the stick zone's correction: -Q/lam 3/(2 pi a b) kappa sqrt(1 - rho^2/kappa^2) on the
            # ellipse scaled by kappa = (1 - lam)^(1/3), with rho = kappa sin t there
            kap = (1.0 - lam) ** (1.0 / 3.0)
            ix, iy = kap * ox, kap * oy
            inner = 3.0 / (2.0 * math.pi * a * b) * kap * c * (kap * kap * area)
            h = np.zeros((3, w.size))
            h[0], h[1] = -fx / lam * inner, -fy / lam * inner
            out = out + self._sum(x0, y0, ix, iy, h)
        return out

    def frame(self, r_mm: float, force: float, x0: float, y0: float, fx: float = 0.0, fy: float = 0.0,
              torque: float = 0.0, lam: float = 0.0) -> np.ndarray:
        """Noise-free readings ``(rows, cols, 3)``."""
        u = self.displacement(r_mm, force, x0, y0, fx, fy, torque, lam) * self.gain
        return u.reshape(self.desc.rows, self.desc.cols, 3)


#: Scene ranges of :func:`scenes`: sphere radius (mm, log-uniform), force (N), mu, lam =
#: Q/(mu P), torsion as a share of Lubkin's gross-slip torque ``3 pi mu P a / 16``.
RANGES = {"r1": (5.0, 20.0), "force": (0.5, 2.0), "mu": (0.3, 1.2), "lam": (0.0, 0.95), "twist": (-0.5, 0.5)}


def scenes(sim: MindlinQuadrature, n: int, rng: np.random.Generator, ranges: dict | None = None
           ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``n`` noisy frames and their truth (fx, fy, torque, mu, lam, q_over_p, slip_margin...),
    the contact within a pitch of the array's centre; ``lam`` spans stick (0) to near slip."""
    r = {**RANGES, **(ranges or {})}
    d = sim.desc
    cx, cy = (d.rows - 1) * d.pitch_x_mm / 2.0, (d.cols - 1) * d.pitch_y_mm / 2.0
    keys = ("r1", "force", "x", "y", "fx", "fy", "torque", "mu", "lam", "q_over_p", "slip_margin")
    truth = {k: np.empty(n) for k in keys}
    frames = np.empty((n, d.rows, d.cols, 3))
    for i in range(n):
        radius = math.exp(rng.uniform(*np.log(r["r1"])))
        force, mu, lam = rng.uniform(*r["force"]), rng.uniform(*r["mu"]), rng.uniform(*r["lam"])
        phi = rng.uniform(0.0, 2.0 * math.pi)
        q = lam * mu * force
        a, _ = sphere_ellipse(radius, force, sim.finger, sim.compliance)
        torque = rng.uniform(*r["twist"]) * 3.0 * math.pi * mu * force * a / 16.0
        x0 = cx + rng.uniform(-0.5, 0.5) * d.pitch_x_mm
        y0 = cy + rng.uniform(-0.5, 0.5) * d.pitch_y_mm
        fx, fy = q * math.cos(phi), q * math.sin(phi)
        clean = sim.frame(radius, force, x0, y0, fx, fy, torque, lam)
        frames[i] = clean + rng.normal(size=clean.shape) * sim.noise
        for k, v in zip(keys, (radius, force, x0, y0, fx, fy, torque, mu, lam, q / force, 1.0 - lam)):
            truth[k][i] = v
    return frames, truth


#: The estimate's keys scored against the truth's.
SCORED = {"fx_n": "fx", "fy_n": "fy", "torque_nmm": "torque", "q_over_p": "q_over_p", "mu": "mu",
          "slip_margin": "slip_margin"}


def score(lines: list[dict], truth: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Per key of :data:`SCORED` over the fitted frames (``tactiled fit``'s JSON lines): the
    share withheld (null), and over the published values the RMS error over the RMS sigma, the
    2-sigma coverage and the share beyond 4 sigma."""
    missed = [line["frame"] for line in lines if not line.get("contact")]
    if missed:
        raise AssertionError(f"frames {missed} were not fitted (no contact found)")
    out = {}
    for key, true in SCORED.items():
        err, sig, withheld = [], [], 0
        for line in lines:
            value, s = line["shear"][key], line["shear"]["std"][key]
            if value is None:
                withheld += 1
                continue
            err.append(value - truth[true][line["frame"]])
            sig.append(s)
        e, s = np.array(err), np.array(sig)
        n = len(lines)
        z = np.abs(e) / s if e.size else np.zeros(0)
        out[key] = {"n": float(e.size), "withheld": withheld / n if n else math.nan,
                    "ratio": float(np.sqrt(np.mean(e ** 2)) / np.sqrt(np.mean(s ** 2))) if e.size else math.nan,
                    "cover": float(np.mean(z <= 2.0)) if e.size else math.nan,
                    "beyond4": float(np.mean(z > 4.0)) if e.size else math.nan}
    return out


def table(rows: list[tuple[str, dict[str, dict[str, float]]]]) -> str:
    """Markdown: per array and key, RMS/CRB, 2-sigma coverage, beyond 4 sigma, withheld."""
    head = "| array | " + " | ".join(SCORED) + " |"
    lines = [head, "|---|" + "---|" * len(SCORED)]
    for name, sc in rows:
        cells = []
        for key in SCORED:
            c = sc[key]
            if c["n"] == 0:
                cells.append(f"- (withheld {c['withheld']:.0%})")
                continue
            cells.append(f"{c['ratio']:.2f} / {c['cover']:.0%} / {c['beyond4']:.0%}"
                         + (f" (withheld {c['withheld']:.0%})" if key in ("mu", "slip_margin") else ""))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def description(spec: str):
    """A 3-axis description: a built-in name, or ``NAME_3axis`` (1-axis NAME made 3-axis)."""
    from tactiled.physics.threeaxis import three_axis
    from tactiled.sensors import load_description

    if spec.endswith("_3axis"):
        return three_axis(load_description(spec[: -len("_3axis")]))
    return load_description(spec)


def fit_through_cli(desc, frames: np.ndarray, workdir) -> list[dict]:
    """``tactiled fit FRAMES.npz --sensor DESC.toml`` in a subprocess: its JSON lines."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    workdir = Path(workdir)
    toml = workdir / f"{desc.name}.toml"
    toml.write_text(desc.to_toml())
    npz = workdir / f"{desc.name}_mindlin.npz"
    np.savez(npz, taxels=frames, sensor=np.str_(str(toml)))
    proc = subprocess.run([sys.executable, "-m", "tactiled.cli", "fit", str(npz), "--sensor", str(toml)],
                          capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr)
    return [json.loads(line) for line in proc.stdout.splitlines()]


ARRAYS = ("xela_uskin_4x4", "xela_uskin_4x6", "flat16_3axis", "fearing1988_3axis", "paxini_px6ax")

#: Scenes at the edge of mu's resolution, ``(array, r1 mm, force N, lam, mu)``: the bound at
#: the truth says a relative sigma of mu near 20 % (torsion a fifth of Lubkin's gross-slip
#: torque, Q at 40 deg, the centre 0.2 mm and -0.1 mm off the array's centre).
EDGE = (("fearing1988_3axis", 15.0, 1.5, 0.65, 0.6), ("fearing1988_3axis", 15.0, 1.5, 0.72, 0.6),
        ("xela_uskin_4x6", 20.0, 2.0, 0.55, 0.6), ("flat16_3axis", 15.0, 1.5, 0.36, 0.6))


def edge_copies(sim: MindlinQuadrature, r1: float, force: float, lam: float, mu: float, n: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The clean frame of one scene and ``n`` noisy copies of it."""
    d = sim.desc
    cx, cy = (d.rows - 1) * d.pitch_x_mm / 2.0, (d.cols - 1) * d.pitch_y_mm / 2.0
    a, _ = sphere_ellipse(r1, force, sim.finger, sim.compliance)
    q, phi = lam * mu * force, 0.7
    torque = 0.2 * 3.0 * math.pi * mu * force * a / 16.0
    clean = sim.frame(r1, force, cx + 0.2, cy - 0.1, q * math.cos(phi), q * math.sin(phi), torque, lam)
    return clean, clean + rng.normal(size=(n,) + clean.shape) * sim.noise


def edge_score(lines: list[dict], mu: float) -> dict[str, float]:
    """The share of copies whose mu is published, and the 2-sigma coverage of those."""
    pub = [line["shear"] for line in lines if line["shear"]["mu"] is not None]
    cover = [abs(s["mu"] - mu) <= 2.0 * s["std"]["mu"] for s in pub]
    return {"published": len(pub) / len(lines), "n": float(len(pub)),
            "cover": float(np.mean(cover)) if pub else math.nan}


def main() -> None:
    """``python tests/fit/mindlin_quadrature.py [--frames N] [--seed S] [ARRAY ...]``: the
    table of :func:`table` on independent frames fitted through ``tactiled fit --sensor``."""
    import argparse
    import tempfile

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("arrays", nargs="*", default=list(ARRAYS))
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--edge", action="store_true", help="the scenes of EDGE, --frames noisy copies each")
    args = p.parse_args()
    if args.edge:
        edge(args.frames, args.seed)
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, spec in enumerate(args.arrays):
            desc = description(spec)
            frames, truth = scenes(MindlinQuadrature(desc), args.frames, np.random.default_rng(args.seed + k))
            rows.append((spec, score(fit_through_cli(desc, frames, tmp), truth)))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    print(table(rows))


def edge(copies: int, seed: int) -> None:
    """Per scene of :data:`EDGE`: whether the bound at the truth resolves mu (the noiseless
    frame's fit), the share of noisy copies publishing mu and their 2-sigma coverage."""
    import tempfile

    from tactiled.fit.shear import ShearFitter

    print("| array | r1 mm | force N | lam | mu | resolved at the truth | published | 2-sigma cover |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (spec, r1, force, lam, mu) in enumerate(EDGE):
            desc = description(spec)
            clean, frames = edge_copies(MindlinQuadrature(desc), r1, force, lam, mu, copies,
                                        np.random.default_rng(seed + k))
            truth = ShearFitter(desc).fit(clean).mu_band()
            sc = edge_score(fit_through_cli(desc, frames, tmp), mu)
            print(f"| {spec} | {r1:g} | {force:g} | {lam:g} | {mu:g} | {'no' if isinstance(truth, str) else 'yes'} "
                  f"| {sc['published']:.0%} | {sc['cover']:.0%} of {sc['n']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
