"""The hand replayed with the tracked run and without it, in turn, in one invocation:
``python -m tactiled_bench.tracked_ab`` (docs/performance/hand.md, "A tracked contact's
frames in one call").  Without it, ``tactiled.pipeline.tracked_run.plan`` answers None: the
calibration stage still goes in runs, a tracked frame takes the per-frame path after it."""

from __future__ import annotations


def main() -> None:
    import sys

    import tactiled.settings as settings
    from tactiled.pipeline import tracked_run
    from tactiled_bench.budget import HAND_PARTS, replay_cost

    # ``python -m tactiled_bench.tracked_ab [FIRST LAST [FRAMES]]``: the hand's parts
    # HAND_PARTS[FIRST:LAST] (default all six), FRAMES frames each (default 4000)
    first, last = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) > 2 else (0, 6)
    frames = int(sys.argv[3]) if len(sys.argv) > 3 else 4000

    load = settings.load_settings  # (a loaded machine starts the fit workers slowly)
    settings.load_settings = lambda path, env, over: load(
        path, env, {**over, "fit.startup_timeout": 600})
    on = tracked_run.plan
    print("| code | round | main process CPU per frame, us (passes) | frames | relinearisations | fits |")
    print("|---|---|---|---|---|---|")
    for k in (1, 2):
        for name, plan in (("tracked runs", on), ("no tracked run", lambda pipe: None)):
            tracked_run.plan = plan
            rs = replay_cost(HAND_PARTS[first:last], frames=frames)
            us = " / ".join(f"{r['us_per_frame']:.1f}" for r in rs)
            print(f"| {name} | {k} | {us} | "
                  f"{rs[-1]['frames']} | {sum(rs[-1]['relinearized'].values())} | "
                  f"{sum(rs[-1]['fits'].values())} |", flush=True)


if __name__ == "__main__":
    main()
