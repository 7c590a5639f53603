"""The benchmark campaign: every planner on every object for several trials, paired seeds,
run in parallel, resumable, and summarised.

- `plan`: the settings, the objects and every episode with its seed and placement;
- `backends`: where episodes run (this process, local processes, Ray);
- `run`: running a campaign into its folder, resuming a finished part;
- `summary`: results.csv and summary.md; `figures`: figure.png and coverage_curves.png.

`lrnbv benchmark` (`lrnbv_drake.cli.benchmark`) is its command line.
"""
