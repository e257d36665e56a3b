"""What ``ultho_report.py`` draws its report with: one module per concern, each importing only those above it.

- ``references``: the fixed reference scores of each benchmark and the normalization they define;
- ``runs``: finding and reading the runs of a study (``Run``, ``Study``) and naming each run's method;
- ``scores``: aggregates with bootstrap intervals, sample efficiency, areas under the learning curves;
- ``decisions``: the bandit's selections, bounds and bonus read back from a ULTHO run's series;
- ``figures``: the PNG figures (matplotlib);
- ``sections``: report.md's sections and tables, one function each;
- ``export``: the compact copy of a study that the results folders commit as ``data/``.

The package lives in the checkout beside the scripts and is not installed by ``pip install .`` (which installs
the bandit and the SB3 callback only).
"""
