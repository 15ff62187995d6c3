"""The real-time iteration's condensed QP solved slack first: a sequence of smaller DAQP QPs.

`SlackFirstQP` solves the dense QP in v = (d, σ) (the inputs that enter the
dynamics, then the static controls: soft bounds' slacks) exactly, first with
every slack held at its lower bound and only the soft rows that need it; see
the class docstring for the optimality test that ends the sequence.
"""

from __future__ import annotations

import daqp
import numpy as np

#: Soft rows closer than this to a bound at the linearization point (scaled units) enter the slack-first
#: sequence's first QP with their slacks fixed (`SlackFirstQP.near`); 0.03 was the fastest of the values
#: tried on four plants (docs/notes/mpc.md).
NEAR = 0.03


class SlackFirstQP:
    """The condensed QP in v = (d, σ), dynamic inputs then slacks (static controls), slacks first
    held at their lower bounds: the exact optimum of the whole QP by a sequence of smaller QPs.

        minimize    ½ vᵀ H v + hᵀ v,        H = [[H_dd, H_σdᵀ], [H_σd, H_σσ]]
        subject to  lba ≤ C v ≤ uba,        C = [C_d, C_σ]
                    lbv ≤ v ≤ ubv

    H_σσ and C_σ are sparse with fixed patterns (their nonzeros change every sample); H_σd is
    absent (zero) unless the slacks couple with the inputs. A slack is held by the rows whose C_σ
    has an entry in its column (its soft rows).

    A restricted QP frees some slacks, keeps the soft rows holding them, and fixes every other
    slack at its lower bound, its soft rows left out (or kept, as rows with the slack fixed). Its
    answer is the whole QP's when (KKT of the whole QP; the restricted QP's own conditions hold already)

    - every left-out soft row holds (zero multiplier), and
    - every fixed slack's Lagrangian gradient (H v + h + Cᵀ λ)_j is >= 0 (its lower bound's
      multiplier has the right sign).

    Otherwise the slacks of the violated rows and those with a negative gradient are freed and the
    restricted QP solved again (all of them, the whole QP, once more than half are free): at most
    one QP per slack, usually one. The first is the QP in the dynamic inputs alone, with the soft
    rows that are within `near` of a bound at v = 0 kept, their slacks fixed: where the last sample's
    answer rode a soft bound without violating it, this one usually does too, and one QP in d with
    those rows replaces a second QP with their slacks free (when DAQP finds the kept rows infeasible
    together, the sequence starts over without them).

    Why: solved whole from DAQP's empty working set, each of the N ns slack bounds that ends up
    active costs one active-set iteration of O(n²) on all N (nu + ns) variables; a sample with
    every soft bound inactive needs only the small QP in d (measurements: docs/notes/mpc.md).

    Without slacks, with slacks that couple with the inputs (H_σd), or with `slack_first` False,
    it is one DAQP call on the whole QP.

    Parameters
    ----------
    n_dynamic, n_static : sizes of d and σ;  m : rows of C
    hessian_pattern, row_pattern : (rows, columns) of the nonzeros of H_σσ and C_σ, in the order
        their values are passed to `solve`
    coupled : H_σd is given (else zero)
    slack_first : try the slacks at their lower bounds first (they must be finite)
    settings : DAQP settings of every solve
    tolerance : violation of a left-out row, and negative gradient of a fixed slack, accepted

    Attributes
    ----------
    near : float or None, `NEAR` when `slack_first`: the first QP's kept soft rows (None: none kept)
    """

    def __init__(
        self,
        n_dynamic: int,
        n_static: int,
        m: int,
        hessian_pattern,
        row_pattern,
        *,
        coupled: bool,
        slack_first: bool,
        settings: dict,
        tolerance: float,
    ):
        self.n_dynamic, self.n_static, self.m = int(n_dynamic), int(n_static), int(m)
        self.hessian_rows, self.hessian_columns = (np.asarray(v, dtype=int) for v in hessian_pattern)
        self.row_rows, self.row_columns = (np.asarray(v, dtype=int) for v in row_pattern)
        self.coupled = bool(coupled)
        self.slack_first = bool(slack_first and self.n_static and not coupled)
        self.soft_rows = np.unique(self.row_rows)
        self.hard_rows = np.setdiff1d(np.arange(self.m), self.soft_rows)
        self.hard_mask = np.zeros(self.m, dtype=bool)
        self.hard_mask[self.hard_rows] = True
        self.every_slack, self.no_slacks = np.arange(self.n_static), np.zeros(0, dtype=int)
        self.near = NEAR if slack_first else None
        self.settings, self.tolerance = dict(settings), float(tolerance)

    def _daqp(self, H, f, A, lower, upper, lba, uba):
        """DAQP on lower ≤ v ≤ upper, lba ≤ A v ≤ uba: (v, bound multipliers, row multipliers, exit flag)."""
        bounds = (np.concatenate([upper, uba]), np.concatenate([lower, lba])) if len(lba) else (upper, lower)
        H, A = np.ascontiguousarray(H), np.ascontiguousarray(A)  # DAQP reads the arrays' memory row by row
        x, _, flag, info = daqp.solve(H, f, A, *bounds, **self.settings)
        lam = info["lam"]
        return x, lam[: len(f)], lam[len(f) :], int(flag)

    def _sparse(self, pattern, values, rows, columns) -> np.ndarray:
        """The dense submatrix (rows, columns) of the sparse matrix with nonzeros `values` at `pattern`."""
        (r, c), n_rows = pattern, max(self.m, self.n_static)
        row_at, column_at = np.full(n_rows, -1), np.full(self.n_static, -1)
        row_at[rows], column_at[columns] = np.arange(len(rows)), np.arange(len(columns))
        keep = (row_at[r] >= 0) & (column_at[c] >= 0)
        out = np.zeros((len(rows), len(columns)))
        out[row_at[r[keep]], column_at[c[keep]]] = values[keep]
        return out

    def whole(self, H_dd, H_sd, hessian_values, C_d, row_values):
        """The whole QP's dense H and C."""
        everything, slacks = np.arange(self.m), np.arange(self.n_static)
        H_ss = self._sparse((self.hessian_rows, self.hessian_columns), hessian_values, slacks, slacks)
        H_sd = H_sd if self.coupled else np.zeros((self.n_static, self.n_dynamic))
        C_s = self._sparse((self.row_rows, self.row_columns), row_values, everything, slacks)
        return np.block([[H_dd, H_sd.T], [H_sd, H_ss]]), np.hstack([C_d, C_s])

    def solve(self, H_dd, H_sd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv):
        """(v, lam_a, lam_x, DAQP exit flag of the last QP, QPs solved) of the QP with these numbers
        (H_sd None unless `coupled`); multipliers in CasADi's convention (H v + h + Cᵀ lam_a + lam_x
        = 0, positive on an active upper bound)."""
        nS = self.n_static
        if not nS:
            x, lam_x, lam_a, flag = self._daqp(H_dd, h, C_d, lbv, ubv, lba, uba)
            return x, lam_a, lam_x, flag, 1
        if not self.slack_first:
            H, C = self.whole(H_dd, H_sd, hessian_values, C_d, row_values)
            x, lam_x, lam_a, flag = self._daqp(H, h, C, lbv, ubv, lba, uba)
            return x, lam_a, lam_x, flag, 1
        started = self._sequence(H_dd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv, self.near)
        if started[3] < 0 and self.near is not None:
            # The soft rows kept with their slacks fixed may be infeasible together: from the hard rows alone.
            *answer, solves = self._sequence(H_dd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv, None)
            return (*answer, solves + started[4])
        return started

    def _sequence(self, H_dd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv, near):
        """`solve`'s sequence of restricted QPs, the soft rows within `near` of a bound at v = 0 kept
        from the start (none when None)."""
        nD, nS, m, tol = self.n_dynamic, self.n_static, self.m, self.tolerance
        hr, hc, cr, cc = self.hessian_rows, self.hessian_columns, self.row_rows, self.row_columns
        h_d, h_s, low_s, high_s = h[:nD], h[nD:], lbv[nD:], ubv[nD:]
        # Masks, not index sets, so each round costs a few vector operations whatever is freed.
        freed = np.zeros(nS, dtype=bool)
        kept = self.hard_mask.copy()  # the rows in the QP: hard, holding a free slack, or near their bound
        if near is not None:
            # Soft rows within `near` of a bound at the linearization point (v = 0) start in the QP with
            # their slacks fixed: where the last answer rode a soft bound, this one likely does too.
            soft = self.soft_rows
            kept[soft[(lba[soft] > -near) | (uba[soft] < near)]] = True
        free, fixed, rows = self.no_slacks, self.every_slack, np.flatnonzero(kept)
        sigma = low_s.copy()  # the fixed slacks' values (the free ones' are set after each solve)
        solves = 0
        while True:
            solves += 1
            soft_kept = rows.size > self.hard_rows.size
            if free.size or soft_kept:
                # The fixed slacks' contributions: to the free slacks' gradient (H_σσ, within a stage)
                # and to the kept rows (C_σ).
                shift = np.bincount(cr, weights=row_values * sigma[cc], minlength=m)[rows]
                lower_rows, upper_rows = lba[rows] - shift, uba[rows] - shift
            else:
                lower_rows, upper_rows = lba[rows], uba[rows]
            if free.size:
                H_sigma = np.bincount(hr, weights=hessian_values * sigma[hc], minlength=nS)
                k = len(free)
                H = np.zeros((nD + k, nD + k))
                H[:nD, :nD] = H_dd
                H[nD:, nD:] = self._sparse((hr, hc), hessian_values, free, free)
                x, lam_v, lam_r, flag = self._daqp(
                    H,
                    np.concatenate([h_d, h_s[free] + H_sigma[free]]),
                    np.hstack([C_d[rows], self._sparse((cr, cc), row_values, rows, free)]),
                    np.concatenate([lbv[:nD], low_s[free]]),
                    np.concatenate([ubv[:nD], high_s[free]]),
                    lower_rows,
                    upper_rows,
                )
            else:  # the QP in d alone, with the hard rows and the kept soft rows
                x, lam_v, lam_r, flag = self._daqp(H_dd, h_d, C_d[rows], lbv[:nD], ubv[:nD], lower_rows, upper_rows)
            sigma[free] = x[nD:]
            v = np.concatenate([x[:nD], sigma])
            lam_a, lam_x = np.zeros(m), np.zeros(nD + nS)
            lam_a[rows] = lam_r
            lam_x[:nD], lam_x[nD + free] = lam_v[:nD], lam_v[nD:]
            if flag < 0 or not fixed.size:
                return v, lam_a, lam_x, flag, solves
            gradient = np.bincount(hr, weights=hessian_values * sigma[hc], minlength=nS) + h_s
            if free.size or soft_kept:  # multipliers only on kept rows, and the hard rows hold no slack
                gradient += np.bincount(cc, weights=row_values * lam_a[cr], minlength=nS)
            gradient = gradient[fixed]
            lam_x[nD + fixed] = -gradient
            left_out = self.soft_rows[~kept[self.soft_rows]]
            values = (C_d @ x[:nD] + np.bincount(cr, weights=row_values * sigma[cc], minlength=m))[left_out]
            violated = np.zeros(m, dtype=bool)
            violated[left_out] = (values < lba[left_out] - tol) | (values > uba[left_out] + tol)
            free_now = np.zeros(nS, dtype=bool)
            free_now[fixed[(gradient < -tol) & (high_s[fixed] > low_s[fixed])]] = True
            free_now[cc[violated[cr]]] = True  # the slacks the violated rows hold
            free_now &= ~freed
            if not free_now.any():
                return v, lam_a, lam_x, flag, solves
            freed |= free_now
            if 2 * freed.sum() > nS:  # about the whole QP already: solve it, not a sequence growing to it
                freed[:] = True
            free, fixed = np.flatnonzero(freed), np.flatnonzero(~freed)
            kept[cr[freed[cc]]] = True  # the rows holding a free slack
            rows = np.flatnonzero(kept)
            sigma[free] = 0.0  # σ holds the fixed slacks' values alone
