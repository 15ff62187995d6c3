"""Parameter uncertainty: the case studies' ±5 % mismatch, sampled reproducibly."""

from __future__ import annotations

import itertools

import numpy as np

from .checks import check_memory, integer, real
from .plant import Plant


def _indices(plant: Plant, names) -> list[int]:
    """Positions in p of the named parameters (default the plant's uncertain ones), checked."""
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a models.Plant, got {type(plant).__name__} {plant!r}")
    if isinstance(names, str):
        raise TypeError(f"names must be a list of parameter names, got the string {names!r}")
    names = plant.uncertain_params if names is None else tuple(names)
    keys = list(plant.params)
    unknown = [n for n in names if n not in keys]
    if unknown:
        raise ValueError(f"{plant.name} has no parameter {unknown}; its parameters are {', '.join(keys)}")
    return [keys.index(n) for n in names]


def _relative(rel) -> float:
    """The relative spread `rel` as a float in [0, 1)."""
    rel = real(rel, "rel", finite=False)
    if not np.isfinite(rel) or not 0 <= rel < 1:
        raise ValueError(f"rel must be in [0, 1), got {rel}")
    return rel


def sample_params(plant: Plant, n: int, rel: float = 0.05, seed: int = 0, names=None) -> np.ndarray:
    """`n` parameter vectors with the named parameters uniform in nominal·[1 − rel, 1 + rel].

    Parameters
    ----------
    plant : the plant whose parameters are sampled (its nominal values are the centres)
    n : number of samples;  rel : relative half-width of the uniform spread
    names : parameters to perturb; default the case study's uncertain ones
    seed : integer >= 0, seed of numpy's default generator; same seed, same samples

    Returns
    -------
    ndarray (n, n_params)
    """
    n = integer(n, "the number of samples n", minimum=1)
    rel = _relative(rel)
    seed = integer(seed, "seed", minimum=0)
    idx = _indices(plant, names)
    check_memory(8.0 * n * (plant.n_params + len(idx)), f"sample_params of {n} samples")
    base = plant.param_vector()
    out = np.tile(base, (n, 1))
    scale = np.random.default_rng(seed).uniform(1 - rel, 1 + rel, size=(n, len(idx)))
    out[:, idx] *= scale
    return out


def corner_params(plant: Plant, rel: float = 0.05, names=None) -> np.ndarray:
    """All 2^k corners nominal·(1 ± rel) of `plant`'s parameters listed in `names` (default: the
    uncertain ones), (2^k, n_params)."""
    rel = _relative(rel)
    idx = _indices(plant, names)
    check_memory(
        8.0 * 2.0 ** len(idx) * plant.n_params, f"corner_params of {len(idx)} parameters (2^{len(idx)} corners)"
    )
    base = plant.param_vector()
    rows = []
    for signs in itertools.product((-1.0, 1.0), repeat=len(idx)):
        row = base.copy()
        row[idx] *= 1 + rel * np.array(signs)
        rows.append(row)
    return np.array(rows)


def perturbed(plant: Plant, rel: float = 0.05, sign: float = 1.0, names=None) -> Plant:
    """The plant with every named parameter scaled by (1 + sign·rel): the text's known model.

    `sign` is +1 or -1; `names` lists the parameters (default: the uncertain ones).
    """
    rel = _relative(rel)
    sign = real(sign, "sign")
    if sign not in (-1.0, 1.0):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    idx = _indices(plant, names)
    keys = list(plant.params)
    return plant.with_params(**{keys[i]: plant.params[keys[i]] * (1 + sign * rel) for i in idx})
