"""What the joint fit changed: statistics of a `fit_bound.py ... SAVE.pt` file.

usage: python models/campaign/v14/fit_stats.py SAVE.pt
"""

import sys

import torch

d = torch.load(sys.argv[1])
op = d["op"]
print(f"opacity median {op.median():.3f} p10 {op.quantile(0.1):.3f}")
dc = (d["col"] - d["vcol"]).abs().max(1).values  # largest channel change
print(f"colour change (max channel) median {dc.median():.3f} p90 {dc.quantile(0.9):.3f}")
sc = torch.exp(d["ls"]).mean(1)  # scale factor vs the 0.3-footprint start, mean of the three axes
print(f"scale factor p10 {sc.quantile(0.1):.2f} p90 {sc.quantile(0.9):.2f}")
off = (d["off"] * 10).norm(dim=1)  # fit_bound's offsets are in units of 0.1 footprint
print(f"offset (footprints) median {off.median():.2f} p90 {off.quantile(0.9):.2f}")
