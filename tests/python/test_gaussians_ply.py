"""PLY interop: the standard 3DGS vertex layout, round trip through .wsplat, clear errors."""

import numpy as np
import pytest
import torch

from worldsplat.gaussians import Gaussians
from worldsplat.gaussians.ply import SH_C0, read_ply, write_ply


def _gaussians(n=300, seed=0):
    gen = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=gen)
    return Gaussians(
        torch.randn(n, 3, generator=gen) * 5,
        q / q.norm(dim=1, keepdim=True),
        torch.rand(n, 3, generator=gen) * 0.5 + 0.01,
        torch.rand(n, generator=gen) * 0.9 + 0.05,
        torch.rand(n, 3, generator=gen),
    )


def test_ply_round_trip_exact_to_float32(tmp_path):
    g = _gaussians()
    write_ply(g, tmp_path / "a.ply")
    h = read_ply(tmp_path / "a.ply")
    for k in ("means", "quats", "scales", "opacities", "colors"):
        assert torch.allclose(getattr(g, k), getattr(h, k), rtol=1e-5, atol=1e-5), k


def test_ply_uses_the_3dgs_conventions(tmp_path):
    g = Gaussians.from_numpy([[1, 2, 3]], [[1, 0, 0, 0]], [[0.5, 0.25, 2.0]], [0.75], [[0.5 + SH_C0, 0.5, 0.0]])
    p = tmp_path / "b.ply"
    write_ply(g, p)
    data = p.read_bytes()
    head, body = data.split(b"end_header\n")
    props = [ln.split()[-1] for ln in head.decode().splitlines() if ln.startswith("property")]
    assert props[:6] == ["x", "y", "z", "nx", "ny", "nz"] and props[6:9] == ["f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    v = np.frombuffer(body, dtype="<f4")
    assert np.allclose(v[6:9], [1.0, 0.0, -0.5 / SH_C0], atol=1e-5)  # colour = 0.5 + C0 * f_dc
    assert np.isclose(v[9], np.log(0.75 / 0.25), atol=1e-5)  # logit opacity
    assert np.allclose(v[10:13], np.log([0.5, 0.25, 2.0]), atol=1e-6)  # log scale
    assert np.allclose(v[13:17], [1, 0, 0, 0])  # rot wxyz


def test_ply_reads_higher_sh_and_doubles(tmp_path):
    n = 4
    props = (
        ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(9)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    dt = np.dtype([(p, "<f8" if p == "x" else "<f4") for p in props])
    rec = np.zeros(n, dtype=dt)
    rec["x"] = [1, 2, 3, 4]
    rec["rot_0"] = 2.0
    head = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 4\n"
        + "".join(f"property {'double' if p == 'x' else 'float'} {p}\n" for p in props)
        + "end_header\n"
    )
    (tmp_path / "c.ply").write_bytes(head.encode() + rec.tobytes())
    g = read_ply(tmp_path / "c.ply")
    assert g.means[:, 0].tolist() == [1, 2, 3, 4] and torch.allclose(g.opacities, torch.full((4,), 0.5))


@pytest.mark.parametrize(
    "data,msg",
    [
        (b"hello", "not a PLY"),
        (b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n", "binary_little_endian"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n", "missing 3DGS"),
    ],
)
def test_ply_errors_are_clear(tmp_path, data, msg):
    (tmp_path / "bad.ply").write_bytes(data)
    with pytest.raises(ValueError, match=msg):
        read_ply(tmp_path / "bad.ply")


def test_ply_truncated_body(tmp_path):
    write_ply(_gaussians(10), tmp_path / "t.ply")
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t2.ply").write_bytes(data[:-7])
    with pytest.raises(ValueError, match="vertices need"):
        read_ply(tmp_path / "t2.ply")
