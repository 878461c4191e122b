"""RAIM Studio web dashboard (viser + plotly): ``python -m app`` or ``raim dashboard``.

Modules: ``server`` (the viser server, one session per browser tab), ``session`` (controls,
recompute, time, export), ``scheduler`` (non-overlapping, coalescing recomputes), ``scene``
(the 3D sky geometry), ``figures`` (pure Plotly figure builders), ``panels`` (the panel
registry keyed on result columns), ``teaching`` (algorithm text and the run's verdict).
This package imports viser and plotly; :mod:`raimcore` never imports it.
"""
