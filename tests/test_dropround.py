"""The compiled fault round (``distnav._dropround``, issue 27) against the mixer's numpy path and the fault schedule.

The kernel must drop exactly the messages :meth:`FaultSchedule.delivered` drops (the same SplitMix64 hash), and a
round must equal the numpy path bit for bit (values and message counts) on drops, failed links, silent nodes, inactive
edges, self-loops, several floats per node and rows longer than the kernel's block. The references are the numpy
path (the same mixer with the kernel switched off) and the schedule's own per-edge decision.
"""

from __future__ import annotations

import weakref
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path

import numpy as np
import pytest

import distnav._dropround as dr
from distnav.exchange import FaultSchedule, make_exchange
from distnav.exchange.faults import FaultPlan
from distnav.network import builders, consensus_weights

BUILT = any((Path(dr.__file__).parent / f"_dropround_c{s}").is_file() for s in EXTENSION_SUFFIXES)
needs_kernel = pytest.mark.skipif(not BUILT, reason="the optional kernel is not built here (numpy path only)")


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def test_built_kernel_loads():
    """A kernel built next to the module must load (a broken build would otherwise fall back silently)."""
    if BUILT:
        assert dr.library() is not None
    else:
        assert dr.library() is None or dr.library() is not None  # nothing built: whatever the environment says


SCHEDULES = {
    "drops": FaultSchedule(drop_probability=0.1, seed=1),
    "heavy drops": FaultSchedule(drop_probability=0.63, seed=2**63 + 5),
    "links and silent": FaultSchedule(
        drop_probability=0.2, failed_links=((0, 1, 2), (3, 4, 0)), silent_nodes=((5, 1), (7, 3)), seed=4
    ),
    "links only": FaultSchedule(failed_links=((0, 1, 1),), silent_nodes=((2, 0),)),
}


def _graph(kind: str):
    if kind == "geometric":
        return builders.connected_random_geometric(400, mean_degree=8, rng=np.random.default_rng(3))
    if kind == "star":  # a hub with 2,999 in-edges: longer than the kernel's 1,024-edge block
        return builders.star(3000)
    return builders.ring(12, self_loops=True)


def _with_links(schedule: FaultSchedule, g) -> FaultSchedule:
    """The schedule's failed links moved onto links of ``g`` (the same rounds), its nodes kept inside ``g``."""
    links = [(int(g.links[i, 0]), int(g.links[i, 1]), r) for i, (_, _, r) in enumerate(schedule.failed_links)]
    silent = tuple((node % g.n_nodes, r) for node, r in schedule.silent_nodes)
    return FaultSchedule(schedule.drop_probability, tuple(links), silent, schedule.seed)


def _pair(g, schedule: FaultSchedule, order: str, active: np.ndarray | None):
    w = consensus_weights(g, "MH")
    mixers = []
    for _ in range(2):
        ex = make_exchange(g, faults=schedule, order=order)
        mixers.append(ex.mixer(w, active=active))
    mixers[1]._kernel = None  # the numpy path
    return mixers


@needs_kernel
@pytest.mark.parametrize("name", list(SCHEDULES))
@pytest.mark.parametrize("kind", ["geometric", "star", "ring with self-loops"])
@pytest.mark.parametrize("floats", [1, 3])
def test_kernel_round_equals_numpy_path_bit_for_bit(name, kind, floats):
    g = _graph(kind)
    schedule = _with_links(SCHEDULES[name], g)
    rng = np.random.default_rng(7)
    active = rng.random(g.n_edges) < 0.9 if kind == "geometric" and floats == 3 else None
    fast, slow = _pair(g, schedule, "auto" if kind == "geometric" else "none", active)
    x = rng.normal(size=(g.n_nodes, floats) if floats > 1 else g.n_nodes)
    xf = xs = fast.exchange.local(x)
    for _ in range(5):
        xf, xs = fast.apply(xf), slow.apply(xs)
        assert isinstance(fast._kernel, dr.DropRound) and slow._kernel is None  # each took its own path
        assert xf.shape == xs.shape and np.array_equal(_bits(xf), _bits(xs))
    a, b = fast.exchange.comm_totals().as_dict(), slow.exchange.comm_totals().as_dict()
    assert a == b and a["messages_dropped"] > 0


@needs_kernel
def test_kernel_rounds_on_reused_changed_and_strided_inputs():
    """The kernel keeps addresses: of its two output buffers, of the last input that was not one of them (read in
    place when C-ordered) and of the last columns. An input changed in place, the same input passed again, a strided
    view (read from a copy), a Fortran-ordered array and another array after them must still give the numpy path's
    bits, round after round."""
    g = builders.connected_random_geometric(300, mean_degree=8, rng=np.random.default_rng(8))
    fast, slow = _pair(g, SCHEDULES["drops"], "auto", None)
    rng = np.random.default_rng(9)
    x = fast.exchange.local(rng.normal(size=g.n_nodes))
    wide = np.asfortranarray(rng.normal(size=(g.n_nodes, 3)))
    strided = rng.normal(size=2 * g.n_nodes)[::2]
    other = x + 1.0
    for step in range(9):
        if step in (3, 6):
            x *= -0.5  # the same arrays, new values
            strided *= -0.5
        inp = {5: strided, 6: strided, 7: wide, 8: other}.get(step, x)
        out_f, out_s = fast.apply(inp), slow.apply(inp)
        assert out_f.shape == out_s.shape == inp.shape and np.array_equal(_bits(out_f), _bits(out_s)), step
    assert isinstance(fast._kernel, dr.DropRound)
    assert fast.exchange.comm_totals().as_dict() == slow.exchange.comm_totals().as_dict()


@needs_kernel
def test_kernel_reads_columns_apart_from_the_values():
    """Under MPI the columns are a buffer of their own (local values, then the halo): the kernel must read them there,
    not at the values' address. Equal columns in another array (C- or Fortran-ordered) give the numpy path's bits;
    columns with other values give another result."""
    g = builders.connected_random_geometric(300, mean_degree=8, rng=np.random.default_rng(10))
    fast, slow = _pair(g, SCHEDULES["drops"], "auto", None)
    x = fast.exchange.local(np.random.default_rng(11).normal(size=(g.n_nodes, 2)))
    kernel = fast._prepare_kernel()
    assert isinstance(kernel, dr.DropRound)
    ref = slow.apply(x)  # round 0 by the numpy path
    lost = np.zeros(g.n_nodes, np.int64)
    for cols in (x.copy(), np.asfortranarray(x)):
        out = kernel.run(x, x, cols, lost, 0, None)
        assert np.array_equal(_bits(out), _bits(ref))
    out = kernel.run(x, x, 2.0 * x, lost, 0, None)
    assert not np.array_equal(out, ref)
    assert lost.sum() == 3 * slow.exchange.comm_totals().messages_dropped > 0


@needs_kernel
@pytest.mark.parametrize("name", list(SCHEDULES))
@pytest.mark.parametrize("edge_dtype", [np.int32, np.int64])
def test_kernel_drops_exactly_the_scheduled_messages(name, edge_dtype):
    g = builders.connected_random_geometric(300, mean_degree=9, rng=np.random.default_rng(5))
    schedule = _with_links(SCHEDULES[name], g)
    edges = np.random.default_rng(6).permutation(g.n_edges).astype(edge_dtype)  # any order, any subset
    src, dst = g.src[edges], g.dst[edges]
    plan = FaultPlan(schedule, src, dst, edges)
    active = np.random.default_rng(8).random(edges.size) < 0.8
    for k in range(6):
        ok = schedule.delivered(k, src, dst, edges)  # the schedule's reference decision
        for act in (None, active):
            lost = dr.lost_mask(
                edges, act, plan.dead_from(k), seed=schedule.seed, round_index=k, threshold=plan.drop_threshold
            )
            assert lost is not None
            assert np.array_equal(lost, (np.ones(edges.size, bool) if act is None else act) & ~ok)


@needs_kernel
def test_kernel_hash_equals_uniform_hash_on_large_ids():
    """Edge ids up to 2⁶³ − 1 and a seed above 2⁶³: the integer threshold decides as ``uniform_hash ≥ p``."""
    from distnav.exchange.faults import uniform_hash

    edges = np.concatenate([np.arange(5000), np.random.default_rng(1).integers(2**40, 2**63 - 1, 5000)])
    p, seed = 0.3, 2**64 - 3
    plan = FaultPlan(FaultSchedule(drop_probability=p, seed=seed), edges, edges + 1, edges)
    for k in (0, 1, 2**31 + 7):
        lost = dr.lost_mask(edges, None, None, seed=seed, round_index=k, threshold=plan.drop_threshold)
        assert lost is not None and np.array_equal(lost, uniform_hash(seed, k, edges) < p)


def test_numpy_path_when_the_kernel_is_missing(monkeypatch):
    """Without the library the mixer takes the numpy path; the round equals the one recomputed by hand."""
    monkeypatch.setattr(dr, "_LIB", [None])
    g = builders.ring(6)
    w = consensus_weights(g, "P3")
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.4, seed=5))
    m = ex.mixer(w)
    x = np.random.default_rng(1).normal(size=6)
    got = m.apply(x)
    assert m._kernel is None
    ok = FaultSchedule(drop_probability=0.4, seed=5).delivered(0, g.src, g.dst, np.arange(g.n_edges))
    dense = w.to_dense()
    ref = np.array(
        [
            dense[i, i] * x[i]
            + sum(dense[i, g.src[e]] * (x[g.src[e]] if ok[e] else x[i]) for e in np.flatnonzero(g.dst == i))
            for i in range(6)
        ]
    )
    assert np.allclose(got, ref, atol=1e-14)


@needs_kernel
def test_non_finite_weight_keeps_the_numpy_path():
    g = builders.ring(8)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.2, seed=1))
    m = ex.mixer(consensus_weights(g, "P3"))
    assert m._w_masked is not None
    m._w_masked.data[3] = np.inf
    assert dr.prepare(m._w_masked, ex._fault_plan.edge_ids, m._act_in, m._self_w) is None


@needs_kernel
def test_read_only_and_strided_values():
    """A read-only or non-contiguous input goes through the kernel and gives the numpy path's bits."""
    g = builders.connected_random_geometric(200, mean_degree=7, rng=np.random.default_rng(9))
    fast, slow = _pair(g, FaultSchedule(drop_probability=0.3, seed=11), "none", None)
    x = np.random.default_rng(4).normal(size=(g.n_nodes, 4))[:, 1]  # a strided column
    x.setflags(write=False)
    a, b = fast.apply(x), slow.apply(x)
    assert isinstance(fast._kernel, dr.DropRound) and np.array_equal(_bits(a), _bits(b))


@needs_kernel
def test_reused_outputs_never_overwrite_a_result_the_caller_holds():
    """The kernel writes into two held buffers, reusing one only when nothing outside refers to it: results kept in
    a list, through a view or under a name must keep their values while later rounds run (each equal, bit for bit,
    to the numpy path's round), and a loop ``x = mixer.apply(x)`` alternates between the two buffers."""
    g = builders.connected_random_geometric(300, mean_degree=8, rng=np.random.default_rng(12))
    fast, slow = _pair(g, SCHEDULES["drops"], "auto", None)
    x = fast.exchange.local(np.random.default_rng(13).normal(size=g.n_nodes))
    kept, refs, views = [], [], []
    xf = xs = x
    for step in range(12):
        xf, xs = fast.apply(xf), slow.apply(xs)
        assert np.array_equal(_bits(xf), _bits(xs)), step
        if step % 3 == 0:
            kept.append(xf)  # held by a list
            refs.append(xs.copy())
        elif step % 3 == 1:
            views.append((xf[::2], xs[::2].copy()))  # only a view of it held
    for got, ref in zip(kept, refs, strict=True):
        assert np.array_equal(_bits(got), _bits(ref))
    for got, ref in views:
        assert np.array_equal(_bits(got), _bits(ref))
    # with nothing held, a loop runs in the kernel's two buffers: no new output array per round (where the reference
    # count is trusted, _REUSE; elsewhere each round makes a new one)
    kernel = fast._kernel
    assert isinstance(kernel, dr.DropRound)
    del kept, views, got, ref
    xf, xs = fast.apply(fast.apply(xf)), slow.apply(slow.apply(xs))  # two rounds: both held buffers free
    held = [weakref.ref(buf) for buf, _ in kernel._out]  # weak: a reference here would keep them from reuse
    for step in range(6):
        xf, xs = fast.apply(xf), slow.apply(xs)
        assert np.array_equal(_bits(xf), _bits(xs))
        assert any(buf is xf for buf, _ in kernel._out), step  # one of the kernel's own buffers
        same = all(buf is was() for (buf, _), was in zip(kernel._out, held, strict=True))
        assert same is dr._REUSE, step  # no new buffer where reused
    assert fast.exchange.comm_totals().as_dict() == slow.exchange.comm_totals().as_dict()


@needs_kernel
def test_without_reuse_every_round_makes_a_new_output(monkeypatch):
    """Where the reference count is not trusted (``_REUSE`` off: CPython 3.14, the free-threaded build, other
    interpreters) no output buffer is reused: every result, kept or not, keeps its values, each round equal bit for
    bit to the numpy path's."""
    monkeypatch.setattr(dr, "_REUSE", False)
    g = builders.connected_random_geometric(300, mean_degree=8, rng=np.random.default_rng(12))
    fast, slow = _pair(g, SCHEDULES["drops"], "auto", None)
    xf = xs = fast.exchange.local(np.random.default_rng(13).normal(size=g.n_nodes))
    results = []
    for step in range(8):
        xf, xs = fast.apply(xf), slow.apply(xs)
        assert np.array_equal(_bits(xf), _bits(xs)), step
        assert all(xf is not got for got, _ in results), step  # a new array every round
        results.append((xf, xs.copy()))
    for step, (got, ref) in enumerate(results):
        assert np.array_equal(_bits(got), _bits(ref)), step


def test_reference_count_reuse_only_where_verified():
    """The reuse rule's reference counts are verified on CPython 3.11–3.13 with the GIL; anywhere else it is off."""
    import sys

    verified = sys.implementation.name == "cpython" and (3, 11) <= sys.version_info[:2] <= (3, 13)
    assert dr._REUSE is (verified and "free-threading" not in sys.version)


def test_round_packer_writes_addresses_unsigned():
    """The per-round fields go into the C struct by one ``struct`` packer: addresses ≥ 2⁶³ (and ≥ 2³¹ with 4-byte
    pointers) must pack, not raise ``struct.error``, and read back through ctypes as written; the two counts stay
    signed."""
    import ctypes

    packer, at = dr._round_packer()
    a = dr._Args()
    values = (-3, 2**40 + 1, 2**64 - 8, 2**63, 2**63 + 64)
    packer.pack_into(memoryview(a).cast("B"), at, *values)
    assert (a.k, a.round_index, a.cols, a.xl, a.y) == values

    class Args32(ctypes.Structure):  # a 32-bit build's layout: 4-byte addresses
        _fields_ = [("k", ctypes.c_int64), ("round_index", ctypes.c_int64)]
        _fields_ += [(name, ctypes.c_uint32) for name in ("cols", "xl", "y")]

    packer, at = dr._round_packer(Args32)
    b = Args32()
    values = (7, -1, 2**31, 2**32 - 4, 2**31 + 8)
    packer.pack_into(memoryview(b).cast("B"), at, *values)
    assert (b.k, b.round_index, b.cols, b.xl, b.y) == values


def test_round_packer_names_an_unknown_field_size():
    import ctypes

    class Odd(ctypes.Structure):
        _fields_ = [("k", ctypes.c_int64), ("round_index", ctypes.c_int64), ("cols", ctypes.c_int16)]
        _fields_ += [(name, ctypes.c_void_p) for name in ("xl", "y")]

    with pytest.raises(RuntimeError, match=r"field 'cols' is 2 bytes on this build \(4 or 8 expected\)"):
        dr._round_packer(Odd)


@needs_kernel
def test_one_float_per_node_shortcut_and_what_it_leaves_to_the_general_path():
    """In a block without remote senders, one float64 per node goes straight to the kernel (apply's general path
    skipped); other dtypes and shapes still take the general path: float32 and integer values are converted (the
    numpy path's bits), a wrong length is refused with the shape named."""
    from distnav.errors import ExchangeError

    g = builders.connected_random_geometric(250, mean_degree=8, rng=np.random.default_rng(14))
    fast, slow = _pair(g, _with_links(SCHEDULES["links and silent"], g), "auto", None)
    rng = np.random.default_rng(15)
    x = fast.exchange.local(rng.normal(size=g.n_nodes))
    inputs = [x, x.astype(np.float32), (100 * x).astype(np.int64), x, x.reshape(-1, 1)]
    for step, inp in enumerate(inputs):
        out_f, out_s = fast.apply(inp), slow.apply(inp)
        assert out_f.shape == out_s.shape == inp.shape and np.array_equal(_bits(out_f), _bits(out_s)), step
        assert fast._kernel_vector == (g.n_nodes,)  # the shortcut is prepared after the first round
    with pytest.raises(ExchangeError, match=r"got array of shape \(249,\)"):
        fast.apply(x[:-1])
    assert fast.exchange.comm_totals().as_dict() == slow.exchange.comm_totals().as_dict()


@needs_kernel
def test_a_plan_that_is_not_the_schedules_own_keeps_the_numpy_path():
    """The field exchange's plan also drops what its network lost (``_NetworkPlan``), which the kernel cannot see: a
    mixer whose exchange has such a plan takes the numpy path, and the extra losses show in the round (checked
    against the round recomputed by hand from the plan's own decisions)."""

    class _ExtraLossPlan:  # a FaultPlan that also loses edge 0's message, as the field's plan wraps the schedule's
        def __init__(self, plan: FaultPlan) -> None:
            self._plan = plan

        def delivered(self, round_index: int) -> np.ndarray:
            ok = np.array(self._plan.delivered(round_index))
            ok[0] = False
            return ok

        def __getattr__(self, name: str) -> object:
            return getattr(self._plan, name)

    g = builders.ring(6)
    w = consensus_weights(g, "P3")
    schedule = FaultSchedule(drop_probability=0.2, seed=3)
    ex = make_exchange(g, faults=schedule)
    plan = ex._fault_plan
    ex.__dict__["_fault_plan"] = _ExtraLossPlan(plan)
    m = ex.mixer(w)
    x = np.random.default_rng(2).normal(size=6)
    got = m.apply(x)
    assert m._kernel is None
    ok = plan.delivered(0).copy()
    ok[0] = False
    src, dst = ex.in_src, ex.nodes[ex.in_dst]
    dense = w.to_dense()
    ref = np.diag(dense) * x
    for e in range(ex.in_edges.size):
        ref[dst[e]] += dense[dst[e], src[e]] * (x[src[e]] if ok[e] else x[dst[e]])
    assert not ok[0] and np.allclose(got, ref, atol=1e-14)


@needs_kernel
def test_counts_after_reset_accounting_equal_the_numpy_path():
    """``reset_accounting`` mid-run: the kernel's rounds after it (one float and two floats per node, so both lost
    counters the mixer holds) must be counted as the numpy path counts them, every counter equal. The mixer keeps
    the exchange's lost-message arrays from its first fault round; a reset that replaced them left the kernel
    writing its losses where no one read them (here 842 messages dropped against the numpy path's 2992 before the
    fix)."""
    g = builders.connected_random_geometric(300, mean_degree=8, rng=np.random.default_rng(12))
    fast, slow = _pair(g, FaultSchedule(drop_probability=0.2, seed=1), "auto", None)
    x = fast.exchange.local(np.random.default_rng(1).normal(size=g.n_nodes))
    wide = fast.exchange.local(np.random.default_rng(2).normal(size=(g.n_nodes, 2)))
    xf = xs = x
    for step in range(8):
        if step == 3:
            fast.exchange.reset_accounting()
            slow.exchange.reset_accounting()
        xf, xs = fast.apply(xf), slow.apply(xs)
        assert np.array_equal(_bits(xf), _bits(xs)), step
    for _ in range(2):
        assert np.array_equal(_bits(fast.apply(wide)), _bits(slow.apply(wide)))
    assert isinstance(fast._kernel, dr.DropRound) and fast._kernel_vector and slow._kernel is None
    a, b = fast.exchange.comm_totals().as_dict(), slow.exchange.comm_totals().as_dict()
    assert a == b and a["rounds"] == 7 and a["messages_dropped"] > 0
    for name in ("messages_sent", "bytes_sent", "messages_received", "bytes_received"):
        assert np.array_equal(getattr(fast.exchange, name), getattr(slow.exchange, name)), name
