"""Record layouts (which fields a record stores, with how many bits) and bit-packing records of a layout."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldsplat.gaussians.wsplat.spec import FIELDS, MAX_POS_BITS_V2, WsplatError


@dataclass(frozen=True)
class Layout:
    fields: tuple[tuple[str, int], ...]

    @property
    def bits(self) -> int:
        return sum(b for _, b in self.fields)

    @property
    def record_size(self) -> int:
        return (self.bits + 7) // 8

    @property
    def isotropic(self) -> bool:
        return any(f == "s" for f, _ in self.fields)

    @property
    def canonical(self) -> bool:
        return any(f == "qx" for f, _ in self.fields)

    def to_json(self) -> list:
        return [[f, b] for f, b in self.fields]


def parse_layout(obj, offset: int, name: str) -> Layout:
    def bad(msg):
        raise WsplatError("bad_layout", offset, f"HEAD.{name}", msg)

    if not isinstance(obj, list) or not obj:
        bad("expected a non-empty list of [field, bits]")
    fields = []
    for item in obj:
        if (
            not isinstance(item, list)
            or len(item) != 2
            or not isinstance(item[0], str)
            or not isinstance(item[1], int)
            or isinstance(item[1], bool)
        ):
            bad(f"entry {item!r} is not [field, bits]")
        f, b = item
        if f not in FIELDS:
            bad(f"unknown field {f!r}")
        if not 1 <= b <= 24:
            bad(f"field {f!r}: bits {b} not in 1..24")
        if f == "qi" and b != 2:
            bad("field 'qi' must have 2 bits")
        if f in ("qx", "qy", "qz") and b < 2:
            bad(f"field {f!r} needs at least 2 bits")
        fields.append((f, b))
    names = [f for f, _ in fields]
    if len(set(names)) != len(names):
        bad("a field appears twice")
    have = set(names)
    for need in ("px", "py", "pz", "o", "r", "g", "b"):
        if need not in have:
            bad(f"missing field {need!r}")
    scales, three, canon = {"sx", "sy", "sz"}, {"qi", "qa", "qb", "qc"}, {"qx", "qy", "qz"}
    if "s" in have:
        if have & (scales | three | canon):
            bad("isotropic 's' excludes sx/sy/sz, qi/qa/qb/qc and qx/qy/qz")
    elif not (scales <= have and ((three <= have and not have & canon) or (canon <= have and not have & three))):
        bad("needs 's', or all of sx sy sz with one rotation: all of qi qa qb qc or all of qx qy qz")
    lay = Layout(tuple(fields))
    if lay.record_size > 16:
        bad(f"record size {lay.record_size} bytes > 16")
    return lay


def pack_records(values: dict[str, np.ndarray], layout: Layout) -> bytes:
    """Integers per field (n,) -> little-endian bit-packed records."""
    n = len(next(iter(values.values())))
    words = np.zeros((n, 2), dtype=np.uint64)
    off = 0
    for f, b in layout.fields:
        x = values[f].astype(np.uint64)
        for w in (0, 1):
            lo = off - 64 * w  # bit position of this field inside word w
            if lo >= 64 or lo + b <= 0:
                continue
            words[:, w] |= (x << np.uint64(lo)) if lo >= 0 else (x >> np.uint64(-lo))
        off += b
    return words.view(np.uint8).reshape(n, 16)[:, : layout.record_size].tobytes()


def unpack_records(raw: bytes | memoryview, n: int, layout: Layout) -> dict[str, np.ndarray]:
    buf = np.zeros((n, 16), dtype=np.uint8)
    buf[:, : layout.record_size] = np.frombuffer(raw, dtype=np.uint8).reshape(n, layout.record_size)
    words = buf.view(np.uint64).reshape(n, 2)
    out, off = {}, 0
    for f, b in layout.fields:
        x = np.zeros(n, dtype=np.uint64)
        for w in (0, 1):
            lo = off - 64 * w
            if lo >= 64 or lo + b <= 0:
                continue
            x |= (words[:, w] >> np.uint64(lo)) if lo >= 0 else (words[:, w] << np.uint64(-lo))
        out[f] = x & np.uint64((1 << b) - 1)
        off += b
    return out


def check_layout_v2(lay: Layout, offset: int, name: str) -> Layout:
    """v2 stores px py pz as one Morton code: the three need the same bits, at most MAX_POS_BITS_V2."""
    b = dict(lay.fields)
    if not b["px"] == b["py"] == b["pz"] or b["px"] > MAX_POS_BITS_V2:
        raise WsplatError(
            "bad_layout", offset, f"HEAD.{name}", f"v2: px py pz need the same bits, at most {MAX_POS_BITS_V2}"
        )
    return lay
