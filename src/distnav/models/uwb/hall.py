"""A realistic simulated UWB anchor network in an industrial hall (issue 13, item 9).

What a real installation under the ceiling of a metal hall looks like, and what this simulator draws (every
draw from one seeded :class:`numpy.random.Generator`):

* **Anchors** on a jittered grid over a ``length_m × width_m`` floor plan (installers follow the roof beams, not
  exactly), mounted under a ceiling at ``ceiling_m``: each anchor hangs ``U(0, drop_max_m)`` below it (brackets,
  beams, cable trays: a few decimetres of height variation). The *surveyed* heights (``heights.csv``) are the
  true heights plus ``N(0, height_survey_sd_m²)``.
* **Links**: every pair closer than ``range_limit_m``; a pair is actually measured with probability
  ``1 − link_loss·(d / range_limit_m)²`` (long links drop out), and only if at least ``min_samples`` ranges got
  through.
* **Installation rule** (``min_links``, default 0 = none): an anchor left with fewer measured partners than
  ``min_links`` gets its shortest dropped pairs back (an installer moves or adds an anchor that sees too few
  others); with 28 anchors, ``link_loss = 0.7``, ``nlos_p1 = 0.15`` and ``min_links = 4`` a hall has about 105
  links (7.5 per anchor) of which 9 % NLOS, the counts of the real 28-anchor plant of issue 13
  (:data:`PLANT_LIKE`).
* **Sample counts**: ``attempts`` ranging exchanges per pair, each succeeding with probability
  ``1 − sample_loss·(d / range_limit_m)`` (weaker signal on long links), so long links have fewer samples.
* **NLOS links** (a shelf, a crane or a pillar in the first Fresnel zone): a measured link is NLOS with
  probability ``nlos_p0 + (nlos_p1 − nlos_p0)·d / range_limit_m`` (likelier with length). An NLOS link has one
  bias ``U(nlos_bias_m)`` (0.5–2.5 m by default) and **every** sample of it is long by that bias plus
  ``|N(0, nlos_spread_m²)|`` (the excess path length fluctuates but is never negative).
* **LOS samples**: the true distance + ``N(0, sigma_m²)``; a fraction ``multipath_fraction`` of them picks up an
  extra positive excess ``Exp(multipath_excess_m)`` (a minority that the median of a pair ignores).
* **Antenna delays**: every node has a range offset ``common_offset_m + N(0, antenna_delay_sd_m²)`` (metres of
  range: the delay × c); a range between a and b is long by ``(δ_a + δ_b) / 2`` (the DS-TWR model
  ``t = d/c + (delay_a + delay_b)/2``, as in the APRIL data's PROVENANCE).

* **Stress-test variations** (``benchmarks/bench_uwb_stress.py``; every one draws nothing at its default, so a
  seed gives the same hall as before they existed): ``nlos_long_fraction`` < 1 (bimodal NLOS links: each sample
  takes the long path with that probability, the others are LOS-like), ``gross_link_fraction`` (that share of the
  links gets ``gross_samples`` samples off by ± ``U(gross_excess_m)``), ``asymmetry_sd_m`` (a→b and b→a samples
  differ by a per-link ``N(0, s²)``, half each way) and ``known_on_wall`` (the known anchors taken from the row
  along the wall ``y = 0``, nearest its middle or its corner: nearly collinear); with ``known_wall_band_m`` they
  are mounted on that wall, ``y ~ U(0, band)`` (collinear within the band: 0.02 m is issue 28's mirror case).
* **LOS range bias** (``los_bias_sd_m``, default 0: no draw): every LOS link gets a bias of its own
  ``N(0, los_bias_sd_m²)`` on all its samples (the DW1000's received-power range bias and multipath that the
  median of a pair does not remove; ``HallNetwork.los_bias_m``). :data:`PLANT_HARD` uses it.

:func:`distnav.formats.uwb.hall_files.hall_csv_texts` gives the CSV files ``distnav uwb solve`` reads
(``ranges.csv`` ``a,b,range_m``; ``known.csv``, ``truth.csv`` ``id,x_m,y_m,z_m``; ``heights.csv`` ``id,z_m``) plus
the labels a user never has (``links_truth.csv``: ``a,b,distance_m,nlos,bias_m``; ``delays.csv``: ``id,offset_m``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from distnav._checks import affordable_nodes, check_field_types
from distnav.errors import ModelError
from distnav.models.uwb.problems import select_fixed
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = ["HallConfig", "HallNetwork", "simulate_hall", "KNOWN_PLACEMENTS", "PLANT_LIKE", "PLANT_HARD"]

KNOWN_PLACEMENTS = ("middle", "corner", "spread")


@dataclass(frozen=True)
class HallConfig:
    """Parameters of :func:`simulate_hall` (defaults: a 28-anchor, 60 m × 30 m hall with a 9 m ceiling)."""

    n_anchors: int = 28
    length_m: float = 60.0
    width_m: float = 30.0
    ceiling_m: float = 9.0
    drop_max_m: float = 0.6
    grid_jitter_m: float = 1.5
    height_survey_sd_m: float = 0.01
    range_limit_m: float = 20.0
    link_loss: float = 0.4
    attempts: int = 60
    sample_loss: float = 0.5
    min_samples: int = 5
    min_links: int = 0
    sigma_m: float = 0.05
    multipath_fraction: float = 0.03
    multipath_excess_m: float = 0.3
    nlos_p0: float = 0.0
    nlos_p1: float = 0.18
    nlos_bias_m: tuple[float, float] = (0.5, 2.5)
    nlos_spread_m: float = 0.08
    common_offset_m: float = 0.0
    antenna_delay_sd_m: float = 0.03
    n_known: int = 4
    known: str = "middle"
    nlos_long_fraction: float = 1.0
    gross_link_fraction: float = 0.0
    gross_samples: int = 3
    gross_excess_m: tuple[float, float] = (2.0, 5.0)
    asymmetry_sd_m: float = 0.0
    known_on_wall: bool = False
    known_wall_band_m: float | None = None
    los_bias_sd_m: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        affordable_nodes(self.n_anchors, "a hall", error=ModelError, items="anchors")
        if self.n_anchors < 4:
            raise ModelError(f"a hall needs at least 4 anchors, got {self.n_anchors}")
        for name in ("length_m", "width_m", "ceiling_m", "range_limit_m"):
            if not getattr(self, name) > 0:
                raise ModelError(f"HallConfig.{name} must be positive, got {getattr(self, name)}")
        for name in (
            "sigma_m",
            "height_survey_sd_m",
            "antenna_delay_sd_m",
            "nlos_spread_m",
            "grid_jitter_m",
            "los_bias_sd_m",
        ):
            if getattr(self, name) < 0:  # a standard deviation (or spread) of a draw
                raise ModelError(f"HallConfig.{name} must be ≥ 0, got {getattr(self, name)}")
        for name in (
            "link_loss",
            "sample_loss",
            "multipath_fraction",
            "nlos_p0",
            "nlos_p1",
            "nlos_long_fraction",
            "gross_link_fraction",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ModelError(f"HallConfig.{name} must be a probability in [0, 1], got {getattr(self, name)}")
        lo, hi = self.nlos_bias_m
        if not 0 <= lo <= hi:
            raise ModelError(f"HallConfig.nlos_bias_m must be (low, high) with 0 ≤ low ≤ high, got {self.nlos_bias_m}")
        glo, ghi = self.gross_excess_m
        if not 0 <= glo <= ghi:
            raise ModelError(
                f"HallConfig.gross_excess_m must be (low, high) with 0 ≤ low ≤ high, got {self.gross_excess_m}"
            )
        if self.gross_samples < 1 or self.asymmetry_sd_m < 0:
            raise ModelError(
                f"need gross_samples ≥ 1 and asymmetry_sd_m ≥ 0, got {self.gross_samples}, {self.asymmetry_sd_m}"
            )
        if self.known_wall_band_m is not None and not (self.known_on_wall and self.known_wall_band_m >= 0):
            raise ModelError(
                f"HallConfig.known_wall_band_m needs known_on_wall and a band ≥ 0 m, got {self.known_wall_band_m}"
            )
        if self.min_links < 0:
            raise ModelError(f"HallConfig.min_links must be ≥ 0, got {self.min_links}")
        if self.attempts < 1 or not 1 <= self.min_samples <= self.attempts:
            raise ModelError(f"need attempts ≥ min_samples ≥ 1, got {self.attempts}, {self.min_samples}")
        if self.known not in KNOWN_PLACEMENTS:
            raise ModelError(f"HallConfig.known must be one of {', '.join(KNOWN_PLACEMENTS)}, got {self.known!r}")
        if not 2 <= self.n_known < self.n_anchors:
            raise ModelError(f"HallConfig.n_known must be in 2..{self.n_anchors - 1}, got {self.n_known}")

    def with_(self, **changes: object) -> HallConfig:
        """A copy with some parameters changed."""
        return replace(self, **changes)  # type: ignore[arg-type]


PLANT_LIKE: dict[str, object] = {"link_loss": 0.7, "nlos_p1": 0.15, "min_links": 4}
""":class:`HallConfig` changes that give the link and NLOS counts of issue 13's real plant (module docstring)."""

PLANT_HARD: dict[str, object] = {
    **PLANT_LIKE,
    "los_bias_sd_m": 0.1,
    "common_offset_m": 0.35,
    "antenna_delay_sd_m": 0.1,
}
"""A plant as hard as issue 28's held-out one: :data:`PLANT_LIKE`'s links and NLOS (≈ 108 links, 9 NLOS of
0.5–2.5 m) plus the range errors of real DW1000 logs, calibrated on the APRIL 8-node logs (``../shared/data/uwb``,
each pair's median range against the surveyed distance, the lab's delays applied; docs/uwb.md, "A plant as hard
as the held-out one"): a common offset of 0.35 m (APRIL: 0.375 / 0.415 m, dataset 4 / 5), per-node delays
N(0, 0.1²) (APRIL's per-node least-squares offsets scatter 0.19 / 0.41 m, an upper bound: with 6 links a node
they are mostly the links' own errors) and a bias per LOS link N(0, 0.1²) (APRIL: 0.28 / 0.47 m after the common
offset, on 1.5–6 m links where the DW1000's received-power bias is largest; 0.1 m puts the default solve at the
held-out plant's 0.21 m with the known anchors in the middle). The per-sample noise stays 5 cm (APRIL's median
per-pair scatter: 0.049 / 0.028 m)."""


@dataclass(frozen=True, eq=False)
class HallNetwork:
    """One simulated hall: truth, links with their NLOS labels, and every range sample.

    ``links`` ``(L, 2)`` anchor indices (i < j) of the measured pairs; ``distance_m``, ``nlos``, ``bias_m`` per
    link (bias 0 for LOS links); ``sample_link`` ``(m,)`` the link of every range sample and ``range_m`` its
    value (in the order written); ``offset_m`` ``(n,)`` every node's range offset (antenna delay × c).
    """

    config: HallConfig
    ids: tuple[str, ...]
    truth_m: FloatArray
    surveyed_z_m: FloatArray
    known: IntArray
    links: IntArray
    distance_m: FloatArray
    nlos: BoolArray
    bias_m: FloatArray
    offset_m: FloatArray
    sample_link: IntArray
    range_m: FloatArray
    swapped: BoolArray = field(repr=False)
    los_bias_m: FloatArray | None = field(default=None, repr=False)  # per link: the LOS range bias (0 on NLOS)

    @property
    def n_anchors(self) -> int:
        return len(self.ids)

    @property
    def samples_per_link(self) -> IntArray:
        counts: IntArray = np.bincount(self.sample_link, minlength=self.links.shape[0]).astype(np.int64)
        return counts

    def sample_pairs(self) -> tuple[list[str], list[str]]:
        """``(a, b)`` ids of every sample, in the direction it was logged (either order occurs)."""
        i, j = self.links[self.sample_link, 0], self.links[self.sample_link, 1]
        a = np.where(self.swapped, j, i)
        b = np.where(self.swapped, i, j)
        return [self.ids[k] for k in a], [self.ids[k] for k in b]


def _layout(cfg: HallConfig, rng: np.random.Generator) -> FloatArray:
    """A jittered grid with about the hall's aspect ratio, ``n_anchors`` cells kept at random if it has more."""
    ny = max(1, int(round(np.sqrt(cfg.n_anchors * cfg.width_m / cfg.length_m))))
    nx = int(np.ceil(cfg.n_anchors / ny))
    gx = (np.arange(nx) + 0.5) * cfg.length_m / nx
    gy = (np.arange(ny) + 0.5) * cfg.width_m / ny
    cells = np.array([(x, y) for y in gy for x in gx])
    keep = np.sort(rng.choice(cells.shape[0], cfg.n_anchors, replace=False))
    xy = cells[keep] + rng.uniform(-cfg.grid_jitter_m, cfg.grid_jitter_m, size=(cfg.n_anchors, 2))
    xy = np.clip(xy, 0.0, [cfg.length_m, cfg.width_m])
    z = cfg.ceiling_m - rng.uniform(0.0, cfg.drop_max_m, cfg.n_anchors)
    out: FloatArray = np.column_stack([xy, z])
    return out


def _known(cfg: HallConfig, truth: FloatArray) -> IntArray:
    xy = truth[:, :2]
    if cfg.known_on_wall and cfg.known != "spread":  # nearly collinear: the row of anchors along the wall y = 0
        ny = max(1, int(round(np.sqrt(cfg.n_anchors * cfg.width_m / cfg.length_m))))
        row = np.argsort(xy[:, 1], kind="stable")[: max(cfg.n_known, cfg.n_anchors // ny)]
        x = xy[row, 0]
        key = np.abs(x - 0.5 * cfg.length_m) if cfg.known == "middle" else x
        wall: IntArray = np.sort(row[np.argsort(key, kind="stable")[: cfg.n_known]]).astype(np.int64)
        return wall
    if cfg.known == "spread":  # one per corner region, then the middle
        corners = np.array([[0, 0], [cfg.length_m, 0], [cfg.length_m, cfg.width_m], [0, cfg.width_m]], float)
        chosen: list[int] = []
        for c in corners[: cfg.n_known]:
            d = np.linalg.norm(xy - c, axis=1)
            d[chosen] = np.inf
            chosen.append(int(np.argmin(d)))
        if cfg.n_known > 4:
            rest = select_fixed(np.delete(xy, chosen, axis=0), "M", cfg.n_known - 4)
            others = np.delete(np.arange(xy.shape[0]), chosen)
            chosen += others[rest].tolist()
        known: IntArray = np.array(sorted(chosen), np.int64)
        return known
    return np.asarray(select_fixed(xy, "M" if cfg.known == "middle" else "C", cfg.n_known), np.int64)


def _restore_links(
    pairs: IntArray, dist: FloatArray, kept: BoolArray, possible: BoolArray, n: int, min_links: int
) -> BoolArray:
    """``kept`` with the shortest dropped (but measurable) pairs of every anchor below ``min_links`` restored."""
    kept = kept.copy()
    for i in range(n):
        mine = np.flatnonzero((pairs[:, 0] == i) | (pairs[:, 1] == i))
        have = int(kept[mine].sum())
        for k in mine[np.argsort(dist[mine])]:
            if have >= min_links:
                break
            if not kept[k] and possible[k]:
                kept[k] = True
                have += 1
    return kept


def simulate_hall(rng: np.random.Generator, config: HallConfig | None = None, **changes: object) -> HallNetwork:
    """Draw one hall network (see the module docstring); ``changes`` override fields of ``config``."""
    cfg = config or HallConfig()
    if changes:
        cfg = cfg.with_(**changes)
    truth = _layout(cfg, rng)
    n = cfg.n_anchors
    if cfg.known_wall_band_m is not None:  # the known anchors mounted on the wall y = 0 (within the band)
        truth[_known(cfg, truth), 1] = rng.uniform(0.0, cfg.known_wall_band_m, cfg.n_known)
    ids = tuple(f"A{k:02d}" if n <= 100 else f"A{k:04d}" for k in range(n))
    surveyed = truth[:, 2] + rng.normal(0.0, cfg.height_survey_sd_m, n)
    offset = cfg.common_offset_m + rng.normal(0.0, cfg.antenna_delay_sd_m, n)

    pairs = cKDTree(truth).query_pairs(cfg.range_limit_m, output_type="ndarray")
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    dist = np.linalg.norm(truth[pairs[:, 0]] - truth[pairs[:, 1]], axis=1)
    rel = dist / cfg.range_limit_m
    kept = rng.random(dist.size) < 1.0 - cfg.link_loss * rel**2
    counts = rng.binomial(cfg.attempts, np.clip(1.0 - cfg.sample_loss * rel, 0.0, 1.0))
    kept &= counts >= cfg.min_samples
    if cfg.min_links > 0:
        kept = _restore_links(pairs, dist, kept, counts >= cfg.min_samples, n, cfg.min_links)
    pairs, dist, rel, counts = pairs[kept], dist[kept], rel[kept], counts[kept]
    n_links = dist.size
    p_nlos = cfg.nlos_p0 + (cfg.nlos_p1 - cfg.nlos_p0) * rel
    nlos = rng.random(n_links) < p_nlos
    bias = np.where(nlos, rng.uniform(cfg.nlos_bias_m[0], cfg.nlos_bias_m[1], n_links), 0.0)

    link = np.repeat(np.arange(n_links), counts)
    m = link.size
    base = dist[link] + 0.5 * (offset[pairs[link, 0]] + offset[pairs[link, 1]])
    noise = rng.normal(0.0, cfg.sigma_m, m)
    multipath = (rng.random(m) < cfg.multipath_fraction) * rng.exponential(cfg.multipath_excess_m, m)
    excess = np.abs(rng.normal(0.0, cfg.nlos_spread_m, m))
    long = nlos[link]
    if cfg.nlos_long_fraction < 1.0:  # bimodal NLOS links: only some samples take the long path (no draw at 1)
        long = long & (rng.random(m) < cfg.nlos_long_fraction)
    r = base + noise + np.where(long, bias[link] + excess, np.where(nlos[link], 0.0, multipath))
    los_bias = np.zeros(n_links)
    if cfg.los_bias_sd_m > 0.0:  # a DW1000 range bias of its own per LOS link (no draw at 0: the same halls)
        los_bias = np.where(nlos, 0.0, rng.normal(0.0, cfg.los_bias_sd_m, n_links))
        r = r + los_bias[link]
    if cfg.gross_link_fraction > 0.0:  # a few gross samples (± a few metres) on some links
        for k in np.flatnonzero(rng.random(n_links) < cfg.gross_link_fraction):
            mine = np.flatnonzero(link == k)
            hit = rng.choice(mine, min(cfg.gross_samples, mine.size), replace=False)
            r[hit] += rng.choice([-1.0, 1.0], hit.size) * rng.uniform(*cfg.gross_excess_m, hit.size)
    r = np.maximum(r, 1e-3)  # a range is never logged ≤ 0 by a DW1000 on these distances
    swapped = rng.random(m) < 0.5
    if cfg.asymmetry_sd_m > 0.0:  # a→b and b→a differ by a per-link amount (e.g. SS-TWR clock drift)
        asym = rng.normal(0.0, cfg.asymmetry_sd_m, n_links)
        r = np.maximum(r + np.where(swapped, 0.5, -0.5) * asym[link], 1e-3)
    return HallNetwork(
        config=cfg,
        ids=ids,
        truth_m=truth,
        surveyed_z_m=surveyed,
        known=_known(cfg, truth),
        links=pairs.astype(np.int64),
        distance_m=dist,
        nlos=nlos,
        bias_m=bias,
        offset_m=offset,
        sample_link=link.astype(np.int64),
        range_m=r,
        swapped=swapped,
        los_bias_m=los_bias,
    )
