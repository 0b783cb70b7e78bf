"""The range coder of .wsplat v2's dynamic records (gaussians.context_coder; web/docs/wsplat-v2.md, "Range-coded
dynamic records"): the integer frequency rule, round trips of chunk sequences with carried models over any layout,
the rescale, and a stream's end (truncated, zero words after it, words that are not 0)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from worldsplat.gaussians import context_coder as cc
from worldsplat.gaussians import wsplat


@settings(max_examples=200, deadline=None)
@given(counts=st.lists(st.integers(0, cc.RESCALE_AT - 1), min_size=2, max_size=64))
def test_frequencies_are_a_24_bit_table_that_follows_the_counts(counts):
    c = np.array(counts)
    if c.sum() >= cc.RESCALE_AT:
        c = c * (cc.RESCALE_AT - 1) // c.sum()
    f = cc.frequencies(c)
    assert f.dtype == np.int64 and f.min() >= 1 and f.sum() == cc.TOTAL
    # the exact rule, one symbol at a time
    k, w = len(c), 2 * c + 1
    left = [int(sum(w[:i])) * (cc.TOTAL - k) // int(w.sum()) + i for i in range(k)] + [cc.TOTAL]
    assert f.tolist() == [left[i + 1] - left[i] for i in range(k)]
    # a symbol seen more often never gets a smaller share (up to the rounding of one step)
    order = np.argsort(c, kind="stable")
    assert (np.diff(f[order]) >= -1).all()


def test_frequencies_of_many_tables_at_once_equal_one_by_one():
    c = np.random.default_rng(0).integers(0, 900, (50, 32))
    np.testing.assert_array_equal(cc.frequencies(c), np.stack([cc.frequencies(r) for r in c]))


def _fields(bits=5):
    return [["px", 13], ["py", 13], ["pz", 13], ["o", bits]]


def test_a_constant_field_costs_nearly_nothing_and_noise_its_bits():
    m = cc.Models(_fields())
    cost: dict = {}
    n = 4000
    cc.encode_chunk(m, np.zeros(n, dtype=np.uint64), {"o": np.full(n, 7, dtype=np.uint64)}, cost)
    assert cost["o"] < 16 * np.log2(n)  # what a KT model pays to learn 31 unused symbols: about 15.5 log2(n) bits
    m = cc.Models(_fields())
    cost = {}
    noise = np.random.default_rng(0).integers(0, 32, n).astype(np.uint64)
    cc.encode_chunk(m, np.zeros(n, dtype=np.uint64), {"o": noise}, cost)
    assert 4.95 < cost["o"] / n < 5.1


def test_contexts_need_the_context_field_earlier_in_the_layout():
    f = {x.name: x for x in cc.coded_fields(wsplat.V2_DYNAMIC_ANISO)}
    assert (f["g"].context, f["g"].context_bits, f["qx"].context, f["o"].context) == ("r", 5, None, "sz")
    f = {x.name: x for x in cc.coded_fields([["px", 4], ["py", 4], ["pz", 4], ["g", 8], ["r", 8], ["b", 9]])}
    assert (f["g"].context, f["r"].context, f["b"].context, f["b"].context_bits, f["b"].adaptive) == (
        None,
        None,
        "g",
        6,
        6,
    )
    assert all(x.context is None for x in cc.coded_fields(wsplat.V2_DYNAMIC_ANISO, context=False))


def random_layout(draw_bits, iso: bool):
    pb, sb, ob, cb, qb = draw_bits
    if iso:
        return [["px", pb], ["py", pb], ["pz", pb], ["s", sb], ["o", ob], ["r", cb], ["g", cb], ["b", cb]]
    return [["px", pb], ["py", pb], ["pz", pb], ["qx", qb], ["qy", qb], ["qz", qb], ["sx", sb], ["sy", sb],
            ["sz", sb], ["o", ob], ["r", cb], ["g", cb], ["b", cb]]  # fmt: skip


def random_chunk(rng, fields, n):
    pb = dict(fields)["px"]
    bl = rng.integers(0, 3 * pb + 1, n)  # Morton deltas of every bit length
    delta = np.array(
        [0 if b == 0 else (1 << (b - 1)) | int(rng.integers(0, 1 << max(b - 1, 0))) for b in bl], np.uint64
    )
    vals = {f: rng.integers(0, 1 << b, n).astype(np.uint64) for f, b in fields if f not in cc.POSITION_FIELDS}
    if "g" in vals:  # a dependent channel, so the contexts matter
        vals["g"] = np.minimum(vals["r"] + rng.integers(0, 2, n).astype(np.uint64), (1 << dict(fields)["g"]) - 1)
    return delta.astype(np.uint64), vals


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    bits=st.tuples(st.integers(1, 21), st.integers(1, 24), st.integers(1, 10), st.integers(1, 9), st.integers(2, 8)),
    iso=st.booleans(),
    sizes=st.lists(st.integers(1, 120), min_size=1, max_size=4),
    seed=st.integers(0, 2**16),
)
def test_property_chunks_round_trip_with_models_carried(bits, iso, sizes, seed):
    fields = random_layout(bits, iso)
    rng = np.random.default_rng(seed)
    enc, dec = cc.Models(fields), cc.Models(fields)
    for n in sizes:
        delta, vals = random_chunk(rng, fields, n)
        words = cc.encode_chunk(enc, delta, vals)
        got_delta, got = cc.decode_chunk(dec, words, n)
        np.testing.assert_array_equal(got_delta, delta)
        for f, v in vals.items():
            np.testing.assert_array_equal(got[f], v, err_msg=f)
    for k in enc.tables:
        np.testing.assert_array_equal(enc.tables[k], dec.tables[k])


def test_a_chunk_decodes_only_with_the_models_of_the_chunks_before_it():
    fields = wsplat.V2_DYNAMIC_ANISO
    rng = np.random.default_rng(3)
    enc = cc.Models(fields)
    chunks = [random_chunk(rng, fields, 200) for _ in range(2)]
    words = [cc.encode_chunk(enc, d, v) for d, v in chunks]
    try:  # the second chunk with fresh models: another stream
        d, v = cc.decode_chunk(cc.Models(fields), words[1], 200)
        assert not (np.array_equal(d, chunks[1][0]) and all(np.array_equal(v[f], chunks[1][1][f]) for f in v))
    except cc.StreamError:
        pass


def test_rescale_halves_a_context_and_both_sides_agree(monkeypatch):
    monkeypatch.setattr(cc, "RESCALE_AT", 64)
    monkeypatch.setattr(cc, "PIECE", 50)  # steps that end at a rescale and steps that do not
    fields = [["px", 3], ["py", 3], ["pz", 3], ["r", 5], ["g", 5], ["b", 5], ["s", 4], ["o", 2]]
    rng = np.random.default_rng(4)
    enc, dec = cc.Models(fields), cc.Models(fields)
    for n in (300, 7, 1000):
        delta, vals = random_chunk(rng, fields, n)
        got_delta, got = cc.decode_chunk(dec, cc.encode_chunk(enc, delta, vals), n)
        np.testing.assert_array_equal(got_delta, delta)
        for f, v in vals.items():
            np.testing.assert_array_equal(got[f], v)
    for k, t in enc.tables.items():
        np.testing.assert_array_equal(t, dec.tables[k])
        assert t.sum(1).max() < 64, k


def test_the_stream_ends_where_its_symbols_end():
    fields = wsplat.V2_DYNAMIC_ISO
    rng = np.random.default_rng(5)
    outcomes = set()
    for seed in range(40):
        delta, vals = random_chunk(np.random.default_rng(seed), fields, int(rng.integers(1, 60)))
        words = cc.encode_chunk(cc.Models(fields), delta, vals)
        n = len(delta)
        # zero words after the stream (an encoder's padding) decode the same
        d, _ = cc.decode_chunk(cc.Models(fields), np.concatenate([words, np.zeros(3, np.uint32)]), n)
        np.testing.assert_array_equal(d, delta)
        with pytest.raises(cc.StreamError) as e:
            cc.decode_chunk(cc.Models(fields), np.concatenate([words, [0, 5]]).astype(np.uint32), n)
        assert e.value.what == "padding" and e.value.word >= len(words)
        with pytest.raises(cc.StreamError) as e:  # two words short: always more than the one read past the end
            cc.decode_chunk(cc.Models(fields), words[:-2], n)
        assert e.value.what in ("truncated", "symbol")
        # one word short decodes only where the stream's last word is a 0 the decoder may read past the end
        try:
            d, _ = cc.decode_chunk(cc.Models(fields), words[:-1], n)
        except cc.StreamError as e:
            outcomes.add(e.what)
        else:
            assert words[-1] == 0
            np.testing.assert_array_equal(d, delta)
            outcomes.add("zero tail")
    assert "truncated" in outcomes, outcomes


@settings(max_examples=100, deadline=None)
@given(words=st.lists(st.integers(0, 2**32 - 1), max_size=12), n=st.integers(1, 40))
def test_property_garbage_words_raise_stream_error_or_decode(words, n):
    try:
        d, v = cc.decode_chunk(cc.Models(wsplat.V2_DYNAMIC_ANISO), np.array(words, dtype=np.uint32), n)
    except cc.StreamError as e:
        assert e.what in ("symbol", "truncated", "padding")
    else:
        assert len(d) == n and all(len(x) == n for x in v.values())
