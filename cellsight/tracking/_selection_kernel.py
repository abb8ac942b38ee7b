"""The compiled search of the optimal feature selection (for :mod:`.selection`, whose docstring
defines the quality ``J`` and the constraint).

Search (compiled with Numba, runs at frame rate). For fixed counts ``n_c`` the balance ``Q_b`` is
fixed and ``J`` separates into independent per-camera problems, so:

1. greedy: per eligible camera, for every count ``n`` the other cameras can complete to ``k``
   (``k - n`` zero or at least ``min_per_camera``), two greedy sets: forward (farthest-point
   seed of ``min_per_camera`` points, then the best addition each time) and backward (from all
   the camera's visible points, the best removal each time); the better gives ``Q_c(n)``;
2. count vectors (each ``n_c`` 0 or feasible, summing to ``k``) are enumerated exhaustively
   (when none exists, e.g. 5 + 5 visible points, ``k = 6``, at least 4 each, ``k`` is lowered
   until one does);
3. exchange: the counts of the best vector are polished: first-improvement single exchanges
   (swap a selected point for an unselected one while ``Q_c`` improves) from both greedy sets,
   then, from the better, double exchanges (two for two), each followed by single ones, while
   they improve (when the double-exchange neighbourhood has at most ``max_pair_exchanges``
   members, which keeps the worst case, 16 visible points per camera, at frame rate).
   Steps 2-3 repeat, an unpolished ``Q_c`` counting as ``(1 + polish_slack)`` times its greedy
   value, until the best vector is made of polished counts only.
"""

import numba
import numpy as np


@numba.njit(cache=True)
def _indexes(px, members, n):
    """(Q_s numerator ``mean_j |x_j - xbar|``, Q_a) of the points ``px[members[:n]]``."""
    if n < 2:
        return 0.0, 0.0
    mx = 0.0
    my = 0.0
    for j in range(n):
        mx += px[members[j], 0]
        my += px[members[j], 1]
    mx /= n
    my /= n
    dsum = 0.0
    c1 = 0.0
    s1 = 0.0
    c2 = 0.0
    s2 = 0.0
    for j in range(n):
        dx = px[members[j], 0] - mx
        dy = px[members[j], 1] - my
        r2 = dx * dx + dy * dy
        if r2 > 0.0:
            r = np.sqrt(r2)
            dsum += r
            c1 += dx / r  # cos(theta)
            s1 += dy / r
            c2 += (dx * dx - dy * dy) / r2  # cos(2 theta)
            s2 += 2.0 * dx * dy / r2
    m1 = np.sqrt(c1 * c1 + s1 * s1) / n
    m2 = np.sqrt(c2 * c2 + s2 * s2) / n
    return dsum / n, max(0.0, (1.0 - m1) * (1.0 - m2))


@numba.njit(cache=True)
def _spread_index(spread, radius):
    """``Q_s = min(1, spread / r_c)`` (0 for a camera without spread to normalise by)."""
    return min(1.0, spread / radius) if radius > 0 else 0.0


@numba.njit(cache=True)
def balance_index(counts, weights, eligible, k):
    """``Q_b = 1 - sum_{eligible c} |n_c - k w_c| / (2 k)`` (0 when ``k`` is 0)."""
    dev = 0.0
    for c in range(len(counts)):
        if eligible[c]:
            dev += abs(counts[c] - k * weights[c])
    return 1.0 - dev / (2.0 * k) if k else 0.0


@numba.njit(cache=True)
def _quality(px, members, n, radius):
    """``Q_c = Q_s Q_a`` of the points ``px[members[:n]]``."""
    spread, qa = _indexes(px, members, n)
    return _spread_index(spread, radius) * qa


@numba.njit(cache=True)
def _exchange(px, members, n, radius, passes):
    """First-improvement exchanges between ``members[:n]`` (selected) and ``members[n:]``,
    cycling over the selected slots until ``n`` slots in a row bring no improvement (a local
    optimum) or ``passes`` cycles are spent; returns the final ``Q_c``. ``members`` is a
    permutation of the camera's candidates."""
    F = len(members)
    q = _quality(px, members, n, radius)
    idle = 0
    a = 0
    for _ in range(passes * n):
        improved = False
        for b in range(n, F):
            members[a], members[b] = members[b], members[a]
            val = _quality(px, members, n, radius)
            if val > q + 1e-12:
                q = val
                improved = True
            else:
                members[a], members[b] = members[b], members[a]
        idle = 0 if improved else idle + 1
        if idle >= n:
            break
        a = (a + 1) % n
    return q


@numba.njit(cache=True)
def _chains(px, radius, n_lo, n_hi):
    """Greedy chains of one camera, ``Q_c`` and permutation (first ``n`` selected) for every
    count ``n`` in ``[n_lo, n_hi]``: row 0 forward (farthest-point seed of ``n_lo`` points, then
    the best addition each time), row 1 backward (from all the points, the best removal each
    time)."""
    F = len(px)
    q = np.full((2, n_hi + 1), -1.0)
    perms = np.zeros((2, n_hi + 1, F), dtype=np.int64)
    perm = np.arange(F)
    mx = 0.0
    my = 0.0
    for i in range(F):
        mx += px[i, 0] / F
        my += px[i, 1] / F
    b = 0
    far = -1.0
    for i in range(F):
        d = (px[i, 0] - mx) ** 2 + (px[i, 1] - my) ** 2
        if d > far:
            far = d
            b = i
    perm[0], perm[b] = perm[b], perm[0]
    mind = np.empty(F)
    for i in range(F):
        mind[i] = (px[i, 0] - px[b, 0]) ** 2 + (px[i, 1] - px[b, 1]) ** 2
    for j in range(1, n_lo):  # farthest-point seed
        b = j
        for i in range(j, F):
            if mind[perm[i]] > mind[perm[b]]:
                b = i
        perm[j], perm[b] = perm[b], perm[j]
        p = perm[j]
        for i in range(F):
            mind[i] = min(mind[i], (px[i, 0] - px[p, 0]) ** 2 + (px[i, 1] - px[p, 1]) ** 2)
    for n in range(n_lo, n_hi + 1):
        if n > n_lo:  # greedy addition into slot n - 1
            b_best = n - 1
            q_best = -1.0
            for b in range(n - 1, F):
                perm[n - 1], perm[b] = perm[b], perm[n - 1]
                val = _quality(px, perm, n, radius)
                if val > q_best:
                    q_best = val
                    b_best = b
                perm[n - 1], perm[b] = perm[b], perm[n - 1]
            perm[n - 1], perm[b_best] = perm[b_best], perm[n - 1]
        q[0, n] = _quality(px, perm, n, radius)
        perms[0, n] = perm
    perm = np.arange(F)
    if F <= n_hi:
        q[1, F] = _quality(px, perm, F, radius)
        perms[1, F] = perm
    for n in range(F - 1, n_lo - 1, -1):  # greedy removal into slot n
        a_best = n
        q_best = -1.0
        for a in range(n + 1):
            perm[a], perm[n] = perm[n], perm[a]
            val = _quality(px, perm, n, radius)
            if val > q_best:
                q_best = val
                a_best = a
            perm[a], perm[n] = perm[n], perm[a]
        perm[a_best], perm[n] = perm[n], perm[a_best]
        if n <= n_hi:
            q[1, n] = q_best
            perms[1, n] = perm
    return q, perms


@numba.njit(cache=True)
def _pair_exchange(px, members, n, radius, q):
    """One first-improvement double exchange (two selected points for two unselected ones);
    returns the new ``Q_c`` (``q`` if none improves)."""
    F = len(members)
    for a1 in range(n):
        for a2 in range(a1 + 1, n):
            for b1 in range(n, F):
                for b2 in range(b1 + 1, F):
                    members[a1], members[b1] = members[b1], members[a1]
                    members[a2], members[b2] = members[b2], members[a2]
                    val = _quality(px, members, n, radius)
                    if val > q + 1e-12:
                        return val
                    members[a2], members[b2] = members[b2], members[a2]
                    members[a1], members[b1] = members[b1], members[a1]
    return q


@numba.njit(cache=True)
def _polish(px, radius, n, starts, passes, max_pairs):
    """Single exchanges to a local optimum from the two chains' sets of ``n`` points (once if
    they are the same set), then from the better one double exchanges, each followed by single
    ones, while they improve (only when a double-exchange pass has at most ``max_pairs``
    candidates); returns the final ``Q_c`` and its permutation."""
    F = len(px)
    best_q = -1.0
    best_perm = starts[0].copy()
    mark = np.zeros(F, dtype=np.bool_)
    for a in range(n):
        mark[starts[0, a]] = True
    same = True
    for a in range(n):
        same = same and mark[starts[1, a]]
    for s in range(1 if same else 2):
        perm = starts[s].copy()
        q = _exchange(px, perm, n, radius, passes)
        if q > best_q + 1e-12:
            best_q = q
            best_perm = perm
    pairs = n * (n - 1) // 2 * ((F - n) * (F - n - 1) // 2)
    for _ in range(passes if pairs <= max_pairs else 0):  # double exchanges, then single ones
        q = _pair_exchange(px, best_perm, n, radius, best_q)
        if q <= best_q:
            break
        best_q = _exchange(px, best_perm, n, radius, passes)
    return best_q, best_perm


@numba.njit(cache=True)
def _best_counts(est, done, weights, eligible, k, m_min, slack):
    """Count vector (each count 0 or one with an estimate, summing to ``k``) of largest ``J``,
    an unpolished estimate counting as ``min(1, est (1 + slack))``."""
    C = len(weights)
    counts = np.zeros(C, dtype=np.int64)
    best_counts = np.zeros(C, dtype=np.int64)
    best_j = -1.0
    while True:  # odometer
        total = 0
        num = 0.0
        for c in range(C):
            total += counts[c]
            if eligible[c]:
                e = est[c, counts[c]]
                num += weights[c] * (e if done[c, counts[c]] else min(1.0, e * (1.0 + slack)))
        if total == k:
            J = num * balance_index(counts, weights, eligible, k)
            if J > best_j:
                best_j = J
                best_counts[:] = counts
        c = 0
        while c < C:  # next feasible value of digit c, else reset it and carry
            counts[c] = max(counts[c] + 1, m_min)
            while counts[c] <= k and est[c, counts[c]] < 0:
                counts[c] += 1
            if counts[c] <= k:
                break
            counts[c] = 0
            c += 1
        if c == C:
            break
    return best_counts, best_j


@numba.njit(cache=True)
def pack(pixels, visible, rho, m_min):
    """Visible candidates per camera (indices, count), radius ``r_c``, eligibility, ``w_c``."""
    C, F = visible.shape
    cand = np.zeros((C, F), dtype=np.int64)
    sizes = np.zeros(C, dtype=np.int64)
    radius = np.zeros(C)
    eligible = np.zeros(C, dtype=np.bool_)
    weights = np.zeros(C)
    for c in range(C):
        mx = 0.0
        my = 0.0
        for f in range(F):
            if visible[c, f] and np.isfinite(pixels[c, f, 0]) and np.isfinite(pixels[c, f, 1]):
                cand[c, sizes[c]] = f
                sizes[c] += 1
                mx += pixels[c, f, 0]
                my += pixels[c, f, 1]
        n = sizes[c]
        for j in range(n):
            f = cand[c, j]
            d = (pixels[c, f, 0] - mx / n) ** 2 + (pixels[c, f, 1] - my / n) ** 2
            radius[c] = max(radius[c], np.sqrt(d))
        eligible[c] = n >= m_min and rho[c] > 0
        if eligible[c]:
            weights[c] = rho[c]
    if weights.sum() > 0:
        weights /= weights.sum()
    return cand, sizes, radius, eligible, weights


@numba.njit(cache=True)
def final_indexes(pixels, selected, radius):
    C, F = selected.shape
    qs = np.zeros(C)
    qa = np.zeros(C)
    members = np.zeros(F, dtype=np.int64)
    for c in range(C):
        n = 0
        for f in range(F):
            if selected[c, f]:
                members[n] = f
                n += 1
        spread, qa[c] = _indexes(pixels[c], members, n)
        qs[c] = _spread_index(spread, radius[c])
    return qs, qa


@numba.njit(cache=True)
def search(pixels, visible, rho, k_max, m_min, passes, slack, max_pairs):
    """The whole selection; returns (selected (C, F), J, k, weights, eligible, radius)."""
    C, F = visible.shape
    cand, sizes, radius, eligible, weights = pack(pixels, visible, rho, m_min)
    selected = np.zeros((C, F), dtype=np.bool_)
    if not eligible.any():  # fallback: every visible point, up to k_max
        left = k_max
        for c in range(C):
            for j in range(min(left, sizes[c])):
                selected[c, cand[c, j]] = True
            left -= min(left, sizes[c])
        return selected, 0.0, k_max - left, weights, eligible, radius
    avail = 0
    for c in range(C):
        if eligible[c]:
            avail += min(sizes[c], k_max)
    k = min(avail, k_max)
    est = np.full((C, k + 1), -1.0)  # Q_c estimates per count (-1: infeasible)
    done = np.zeros((C, k + 1), dtype=np.bool_)  # polished by exchanges
    chain_perms = np.zeros((C, 2, k + 1, F), dtype=np.int64)
    perms = np.zeros((C, k + 1, F), dtype=np.int64)
    cams_px = np.zeros((C, F, 2))
    for c in range(C):
        est[c, 0] = 0.0
        done[c, 0] = True
        n_hi = min(sizes[c], k)
        if eligible[c] and n_hi >= m_min:
            for j in range(sizes[c]):
                cams_px[c, j] = pixels[c, cand[c, j]]
            q, p = _chains(cams_px[c, : sizes[c]], radius[c], m_min, n_hi)
            others = avail - min(sizes[c], k_max)
            for n in range(m_min, n_hi + 1):
                # only counts the other cameras can complete to k (0 or >= m_min each)
                if n == k or m_min <= k - n <= others:
                    est[c, n] = max(q[0, n], q[1, n])
            chain_perms[c, :, : n_hi + 1, : sizes[c]] = p
    while True:  # polish the counts of the best vector until it is made of polished counts
        best_counts, best_j = _best_counts(est, done, weights, eligible, k, m_min, slack)
        fresh = False
        for c in range(C):
            n = best_counts[c]
            if not done[c, n]:
                F_c = sizes[c]
                q, p = _polish(cams_px[c, :F_c], radius[c], n, chain_perms[c, :, n, :F_c],
                               passes, max_pairs)
                est[c, n] = q
                perms[c, n, :F_c] = p
                done[c, n] = True
                fresh = True
        if not fresh:
            break
    for c in range(C):
        for j in range(best_counts[c]):
            selected[c, cand[c, perms[c, best_counts[c], j]]] = True
    return selected, best_j, k, weights, eligible, radius
