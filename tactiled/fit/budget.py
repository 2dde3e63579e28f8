"""A fit's budget: what one frame may cost before the fitter stops and says so."""

# A frame the contact model describes converges in a few tens of solver iterations, each a
# model evaluation of a few microseconds.  A frame it cannot describe (several contacts at once,
# a hand print, a saturated patch, noise) has no good minimum: the search wanders until its caps,
# through starts and models, and where it wanders to a contact many rubber depths long, every
# evaluation integrates a quadrature of up to a million nodes.  Unbounded, such a frame cost
# tens to thousands of milliseconds.  The budget bounds it in two counts that do not depend on
# the machine, so a frame gets the same answer on every CPU:
#
# - **iterations**: Levenberg-Marquardt iterations summed over every start and model of the fit;
# - **work**: the model evaluations' cost, each ``EVALUATION_OVERHEAD`` plus its quadrature
#   nodes times the window's tactels (the inner loop's count: 2.3-3.4 ns each, measured from
#   7x7 to 96x40 nodes on a 4x4 window; beyond ``LARGE_RULE_NODES`` nodes the tables leave the
#   cache and a unit costs up to 7 ns, so those count ``LARGE_RULE_FACTOR`` times); a line
#   model's evaluation (a flat array's cylinder) ``line_work``, in the same units.
#
# An evaluation that the work left cannot pay for is not started.  A wall-clock ``deadline``
# (``Fitter.fit(budget_s=)``) stays the last resort, checked between evaluations.
#
# The defaults are set from the fits the model explains: every fit that converges on the
# simulated suites and in the golden replays stays within both with a margin (figures below), so
# the budget changes none of them (``tactiled bench --suite unexplained``, docs/performance/benchmarks.md).

from __future__ import annotations

import math
from dataclasses import dataclass

#: The solver iterations of one fit, summed over its starts and models.  The fits that
#: converge use at most 95 (the simulated suites, 1200 frames each, auto cold and warm, every
#: kind of contact) and 87 (the golden replays: an edge held at the array's end).
DEFAULT_ITERATIONS = 120
#: The work of one fit (see the module docstring).  A fit that spends it costs ~2.4 ms on
#: the machine of docs/performance/fit-time.md (2.4-3.1 ns a unit in the search, 0.4-0.8 ms of Python
#: around it), within the 3 ms of a frame at the 99th percentile.  The fits that converge use
#: at most 342000 on the paper's finger (the simulated suites) and 616000 in the golden
#: replays (an edge at the end of the array).
DEFAULT_WORK = 800_000
#: A flat array's fits may spend up to this many times the work, and twice the iterations:
#: auto fits the line and then, where the line does not explain the window, the sphere and
#: the general ellipse, whose searches follow a wide blob into large contacts
#: (docs/concepts/fitting.md, "The fit's budget").  The work beyond the base is an
#: *allowance* (``Budget.reserve``), granted only to a fit that earns it: see
#: ``GRANT_CHI2_FACTOR``.
FLAT_WORK_FACTOR = 3
FLAT_ITERATION_FACTOR = 2
#: A search earns the allowance when, at the point the fit's base work is spent, its chi^2
#: is within this many times the most a right model reaches (``right_model_chi2``: its
#: degrees of freedom plus three standard deviations), an order of magnitude.  A search on
#: its way to a model that explains the window is within it: on the simulated contacts of
#: every built-in description (``tactiled bench --suite sensors``) the searches that reach
#: the base work stand at up to ~8 times (a sphere's or an ellipse's scout on a ball wider
#: than the window), bar a rare ellipse scout from a far start (auto then answers with the
#: line that explains the window).  A window no model explains (several contacts, a random
#: pattern) stands at hundreds to tens of thousands of times: its searches stop at the base
#: work, where a fit costs ~2.4 ms (docs/performance/fit-time.md).  A search refused the
#: allowance stops; a later search of the same fit may still earn it.
GRANT_CHI2_FACTOR = 10.0
#: Work units an evaluation costs besides its quadrature (the Hertz solve, the step's linear
#: algebra: ~3 us, measured as the intercept of the cost per evaluation).
EVALUATION_OVERHEAD = 1000
#: Beyond this many quadrature nodes an evaluation's tables (8 bytes x nodes x 4 per window
#: line) leave the cache and each node costs up to ``LARGE_RULE_FACTOR`` times more.
LARGE_RULE_NODES = 8192
LARGE_RULE_FACTOR = 3
#: One evaluation of a flat array's line model (its residuals and their exact Jacobian,
#: compiled: ``tactiled.physics.line.line_residual``): ~2 us plus ~75 ns per node across the
#: line and window tactel (each a residue and its partials), measured from 4 to 256 nodes on
#: 16 to 64 tactels; in units of the ellipse's (~2.1 ns each in its kernel).
LINE_OVERHEAD = EVALUATION_OVERHEAD
LINE_WORK_PER_NODE = 36


#: A line's window is its band, the tactels that see it along its whole length (40-100 on a
#: 16x16 pad: ``tactiled.fit.linewindow``); its evaluations are charged for at most this many
#: tactels, the default 4x4 window's, so that following the line does not cut short the
#: searches auto's share of the budget allows a line on a window (a line's scout from its
#: cold start takes 10-30 evaluations).  A band's evaluation costs up to ~6x what it is
#: charged; the line fits of ``tactiled bench --suite contacts`` take at most ~4 ms.
LINE_CHARGED_TACTELS = 16


def line_work(nodes: int, points: int) -> int:
    """Work units of one evaluation of the line model: ``nodes`` across the line, ``points``
    window tactels (a line's band is charged for at most ``LINE_CHARGED_TACTELS``)."""
    return LINE_OVERHEAD + LINE_WORK_PER_NODE * nodes * points

#: How a fit the budget stopped begins its ``reasons["fit"]`` (and the solver its message).
EXHAUSTED = "fit budget exhausted"
#: The message of a search stopped at its base work, the allowance denied (its chi^2 over
#: ``GRANT_CHI2_FACTOR`` times a right model's there).
DENIED = (f"{EXHAUSTED} (the base work; the flat array's allowance is denied: chi^2 is over "
          f"{GRANT_CHI2_FACTOR:g}x what a right model reaches)")


def right_model_chi2(dof: int) -> float:
    """The most chi^2 a right model reaches with ``dof`` degrees of freedom, bar three
    standard deviations in a thousand: ``dof + 3 sqrt(2 dof)``."""
    return dof + 3.0 * math.sqrt(2.0 * dof)


#: A stopped fit whose remaining distance to the least-squares minimum (the Gauss-Newton
#: step's chi^2 decrease, D) is within this keeps its values with every sigma widened by
#: sqrt(1 + D); beyond it (the minimum over 3 sigma away: the linear picture no longer holds)
#: the values are withheld.
MAX_REMAINING_CHI2 = 9.0


class BudgetExhausted(Exception):
    """Raised by a residual function asked for an evaluation the budget cannot pay for; the
    Python solver stops at the point it has (``levenberg_marquardt``)."""


def evaluation_work(nodes_u: int, nodes_s: int, points: int) -> int:
    """Work units of one evaluation: ``nodes_u x nodes_s`` quadrature nodes over ``points``
    window tactels (``LARGE_RULE_FACTOR`` times that for a rule beyond ``LARGE_RULE_NODES``),
    plus the overhead.  Plain arithmetic: the compiled search (core/search.cpp) repeats it, held equal by
    tests/native."""
    nodes = nodes_u * nodes_s
    return EVALUATION_OVERHEAD + nodes * points * (LARGE_RULE_FACTOR if nodes > LARGE_RULE_NODES else 1)


@dataclass
class Budget:
    """What is left of one fit's budget (None: unlimited).

    ``work`` is what the fit may spend as of right; ``reserve`` an allowance on top of it (a
    flat array's, ``FLAT_WORK_FACTOR``), added to ``work`` (:meth:`grant`) only when the
    search that has spent ``work`` stands at chi^2 within ``GRANT_CHI2_FACTOR`` times a right
    model's (:meth:`grant_cost`)."""

    iterations: int | None = DEFAULT_ITERATIONS
    work: float | None = DEFAULT_WORK
    reserve: float = 0.0
    #: set once a solve stopped for want of budget
    exhausted: bool = False
    #: what the fit has spent so far
    used_iterations: int = 0
    used_work: float = 0.0
    #: the reserve was added to ``work``
    granted: bool = False
    #: a search was refused the reserve (it stopped; the fit goes on)
    denied: bool = False

    def hold(self, share: float) -> tuple[int, float, float]:
        """Set aside ``share`` of what is left (iterations, work and allowance) for later
        searches; returns it for :meth:`release`.  Auto keeps half for the other models while
        it fits the cylinder: a frame the cylinder cannot explain must not leave none to the
        sphere."""
        held_i = 0 if self.iterations is None else int(self.iterations * share)
        held_w = 0.0 if self.work is None else float(self.work) * share
        held_r = self.reserve * share
        if self.iterations is not None:
            self.iterations -= held_i
        if self.work is not None:
            self.work -= held_w
        self.reserve -= held_r
        return held_i, held_w, held_r

    def release(self, held: tuple[int, float, float]) -> None:
        """Give back what :meth:`hold` set aside (the search it was held from is over); a
        held allowance joins the work if the allowance was granted meanwhile."""
        if self.iterations is not None:
            self.iterations += held[0]
        if self.work is not None:
            self.work += held[1] + (held[2] if self.granted else 0.0)
        if not self.granted:
            self.reserve += held[2]
        self.exhausted = False  # what ran out was the share left to that search

    def grant_cost(self, dof: int, unit: float) -> float:
        """The cost (``unit``: the cost of chi^2 = 1) at or below which the next search, with
        ``dof`` degrees of freedom, earns the allowance when it has spent ``work``; -1 when
        there is none to grant."""
        if self.reserve <= 0.0:
            return -1.0
        return GRANT_CHI2_FACTOR * right_model_chi2(dof) * unit

    def grant(self) -> None:
        """Add the allowance to the work (a search reached ``work`` within its grant cost)."""
        if self.work is not None:
            self.work += self.reserve
        self.reserve = 0.0
        self.granted = True

    def iterations_for(self, cap: int) -> int:
        """The iteration cap of the next solve: ``cap``, or what is left if less."""
        return cap if self.iterations is None else max(0, min(cap, self.iterations))

    def work_left(self) -> float:
        return math.inf if self.work is None else max(0.0, float(self.work))

    def charge(self, iterations: int, work: float) -> None:
        self.used_iterations += iterations
        self.used_work += work
        if self.iterations is not None:
            self.iterations -= iterations
        if self.work is not None:
            self.work -= work

    @property
    def spent(self) -> bool:
        return self.exhausted or (self.iterations is not None and self.iterations <= 0) or (
            self.work is not None and self.work < EVALUATION_OVERHEAD and self.reserve <= 0.0)

    def pay(self, cost: float) -> None:
        """Take an evaluation's work, or raise :class:`BudgetExhausted` (marking the budget
        exhausted) when the work left cannot pay for it (the Python solver's searches: the
        allowance is not granted there)."""
        if self.work is not None:
            if cost > self.work:
                self.exhausted = True
                raise BudgetExhausted(EXHAUSTED)
            self.work -= cost
        self.used_work += cost

    def charger(self):
        """A ``charge(nodes_u, nodes_s, points)`` callable for the Python solver's residual
        (:meth:`pay` for its evaluation's work)."""
        def charge(nodes_u: int, nodes_s: int, points: int) -> None:
            self.pay(evaluation_work(nodes_u, nodes_s, points))
        return charge


def budget_spent(reasons: dict[str, str]) -> bool:
    """True when a fit's ``reasons`` (as in its JSON) say the budget stopped it."""
    return reasons.get("fit", "").startswith(EXHAUSTED)


def stopped_by_budget(res: Any) -> bool:
    """True when the budget stopped the fit of result ``res``: its reasons say so, or, for a
    result among several searched only (its reasons written when it is published), its
    solver's message does."""
    return budget_spent(res.reasons) or (res.message or "").startswith(EXHAUSTED)
