"""Speed against error: one benchmark command, one report.

Every section measures one knob that trades speed for accuracy, in this run, on this machine, and returns a
`Section` (a table, optional Pareto plot, the chosen default and why). `worldsplat bench --out DIR` runs them
all and writes `DIR/report.md` with PNG plots; `--quick` shrinks every section so it runs inside `make test`
and checks the trends physics promises (see `checks.py`).
"""
