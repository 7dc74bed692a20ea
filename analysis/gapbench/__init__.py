"""Blind benchmarks of the sim-to-real gap diagnosis (:mod:`analysis.gap`): pseudo-real data with
a hidden effect, written as the lab's files, diagnosed from the files alone, and scored.

Kept apart from the diagnosis they test: :mod:`analysis.gap` imports nothing from this package,
and this package imports the diagnosis only through its public API (``from analysis.gap import
...``: :func:`~analysis.gap.diagnose`, the catalogue, the effect registry and the layers'
likelihoods listed in ``analysis.gap.__all__``); tests/analysis/gapbench/test_independence.py
checks both by parsing the imports.

Modules
-------
benchmark
    The blind benchmark of each layer: in-catalogue, out-of-catalogue and null runs at fixed
    seeds, top-1 identification, false attributions, 'unexplained' rate, shrinkage error,
    detection thresholds, and which layer carries the gap (``TARGETS``, ``run_benchmark``,
    ``run_thresholds``, ``run_layer_benchmark``, ``format_scores``).
inject
    The injectors: the experiment's ideal observers, the calibration's simulated CRT and
    Mitsuba renders of the gloss fit's sphere, each with one effect (a candidate's own injector
    or an out-of-catalogue effect this module registers beside the candidates).
bench_observer, bench_display, bench_render
    The harder benchmark (``--harder``): human-like observers, an independent gain-offset-gamma
    display and an analytic render sphere, written apart from the diagnosis and its injectors;
    co-occurring effects, effects outside the catalogue on top, verdict agreement across seeds.
scoring
    The scores the benchmarks share: rates over cases, seed agreement, shrinkage truth.

Command line: ``python -m analysis gapbench --layer observer|display|render|all ...`` (also
``python -m analysis.gapbench``, and ``python -m analysis gap benchmark ...``, which forwards
here).
"""
