"""Paired comparisons of two methods over training seeds, with the exact sign-flip (permutation) test.

Two methods trained with the same seeds and evaluated on the same held-out copies give one difference per seed. Under
the null hypothesis that the methods do not differ, each difference is as likely to have either sign, so the p-value
is the share of the 2^n sign vectors whose mean difference is at least as far from zero as the observed one.
"""

import numpy as np
import polars as pl

EXACT_MAX_SEEDS = 20  # 2^20 sign vectors enumerated; beyond, a seeded Monte Carlo sample of as many
MONTE_CARLO_SEED = 0
_TIE = 1e-12  # sign vectors whose |mean| equals the observed one up to float rounding count as "as extreme"


def sign_flip_p(differences) -> float:
    """Two-sided p-value of the mean of paired differences (NaN-free 1-d array): exact up to EXACT_MAX_SEEDS
    differences, else estimated from 2^EXACT_MAX_SEEDS random sign vectors (seeded, so reproducible)."""
    d = np.asarray(differences, float)
    if d.ndim != 1 or len(d) == 0 or not np.isfinite(d).all():
        raise ValueError(f"sign_flip_p needs a non-empty 1-d array of finite differences, got {d!r}")
    n = len(d)
    if n <= EXACT_MAX_SEEDS:
        # every signed sum as (sums over the first half's sign vectors) + (sums over the second half's): 2^n values
        # without a 2^n x n matrix
        half = n // 2
        sums = (_signed_sums(d[:half])[:, None] + _signed_sums(d[half:])[None, :]).ravel()
    else:
        signs = 1 - 2 * np.random.default_rng(MONTE_CARLO_SEED).integers(0, 2, (2**EXACT_MAX_SEEDS, n), dtype=np.int8)
        sums = signs @ d
    return float((np.abs(sums) >= abs(d.sum()) - _TIE * n).mean())


def _signed_sums(d: np.ndarray) -> np.ndarray:
    """Σ ± d_k for all 2^len(d) sign vectors."""
    sums = np.zeros(1)
    for x in d:
        sums = np.concatenate([sums + x, sums - x])
    return sums


COMPARISON_SCHEMA = {"method": pl.String, "reference": pl.String, "metric": pl.String, "seeds": pl.Int64, "method_mean": pl.Float64,
                     "reference_mean": pl.Float64, "mean_diff": pl.Float64, "std_diff": pl.Float64, "seeds_higher": pl.Int64,
                     "seeds_lower": pl.Int64, "p_two_sided": pl.Float64}


def paired_comparisons(runs: pl.DataFrame, group: str, pairs: tuple[tuple[str, str], ...], metrics: tuple[str, ...],
                       replicate: str | None = None) -> pl.DataFrame:
    """Each (method, reference) of `pairs` in each `group` (a scenario, a case) where both ran: per seed, each metric's
    mean over the `replicate` rows both methods have (e.g. held-out copies; None: one row per seed), then the paired
    difference method − reference over the seeds both have, its mean ± std, how many seeds are higher / lower, and
    sign_flip_p. A replicate with the metric null on either side counts on neither; a seed with no replicate left is
    out of that metric's pairs."""
    keys = [group, "seed", *([replicate] if replicate else [])]
    values = [pl.col(m).cast(pl.Float64) for m in metrics]
    rows = []
    for method, reference in pairs:
        both = runs.filter(pl.col("method") == method).select(*keys, *values).join(
            runs.filter(pl.col("method") == reference).select(*keys, *values), on=keys, suffix="_ref")
        # a replicate where either side has no value (e.g. no vehicle arrived) is left out on both sides
        paired = [pl.when(pl.col(m).is_not_null() & pl.col(f"{m}_ref").is_not_null()).then(pl.col(c)).alias(c)
                  for m in metrics for c in (m, f"{m}_ref")]
        per_seed = both.with_columns(paired).group_by(group, "seed").agg(pl.exclude(keys).mean()).sort(group, "seed")
        for (where,), g in per_seed.group_by(group, maintain_order=True):
            for metric in metrics:
                pair = g.drop_nulls([metric, f"{metric}_ref"])
                if pair.is_empty():
                    continue
                a, b = pair[metric].to_numpy(), pair[f"{metric}_ref"].to_numpy()
                d = a - b
                rows.append({
                    group: where, "method": method, "reference": reference, "metric": metric, "seeds": len(d),
                    "method_mean": a.mean(), "reference_mean": b.mean(), "mean_diff": d.mean(),
                    "std_diff": float(np.std(d, ddof=1)) if len(d) > 1 else None,
                    "seeds_higher": int((d > 0).sum()), "seeds_lower": int((d < 0).sum()), "p_two_sided": sign_flip_p(d)})
    return pl.DataFrame(rows, schema={group: pl.String, **COMPARISON_SCHEMA})
