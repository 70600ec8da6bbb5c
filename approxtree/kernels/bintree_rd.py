"""The embedded right-triangle binary tree of a (2^k + 1)² grid, and its rate–distortion kernels.

Balmelli, Ayer & Vetterli: decimation by constrained G-BFOS and refinement by greedy growing.

*Node ids* (an implicit complete binary tree): 1 is the whole square (never drawn, always
split), 2 and 3 the two root triangles, and node u has children 2u and 2u + 1. The level of u
is floor(log2 u); the unit triangles of the full grid are the leaves, at level 2k + 1. On the
lattice of side s = 2^k (x = column, y = row) a triangle is (apex a, left l, right r) with
hypotenuse l–r; it splits at the hypotenuse midpoint m into child 2u = (m, l, a) and child
2u + 1 = (m, a, r)::

        a                      a
       / \\                    /|\\
      /   \\        →         / | \\
     l-----r                l--m--r
                          2u      2u+1

*Mate*: the triangle of the same level sharing u's hypotenuse (0 on the domain border). A mesh
of the tree (a set of split nodes, the *internal* set I) is conforming — no T-junctions — iff
every internal node has an internal parent and an internal mate. Hence:

- the *splitting domain* of a leaf t: the nodes that must split with it, {t, mate(t)} and, when
  mate(t) does not exist yet, the splitting domain of its parent (the coarser leaf across t's
  hypotenuse);
- the *merging domain* of an internal node t: every internal node that depends on t through
  parent and mate links; it is a union of whole subtrees whose roots are t, mate(t) and the
  mates of the children of every root (further boundary descendants have their mates inside
  those subtrees).

*Distortion* d(u): the sum of squared errors of the grid points of triangle u against its
plane, a point on an edge weighted 1/2 (1 on the domain border). In a conforming mesh every
interior edge is shared by exactly two triangles with the same interpolation along it, so the
mesh's distortion — the sum over all grid points, each once — is the sum of d over its
leaves. gain(u) = d(u) − d(2u) − d(2u + 1) is what splitting u saves (it may be negative).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels.tin_mesh import orient
from approxtree.kernels.tin_scan import row_span
from approxtree.kernels.tri_heap import heap_push, heap_remove, heap_update

#: Step of a node that never splits in a sequence.
NEVER = np.int32(2**31 - 1)


@njit(cache=True, inline="always")
def node_level(u: int) -> int:
    """floor(log2 u)."""
    lev = 0
    while u > 1:
        u >>= 1
        lev += 1
    return lev


@njit(cache=True)
def node_corners(u: int, k: int):
    """(ax, ay, lx, ly, rx, ry) of node u >= 2 on the lattice of side 2^k (descends from root)."""
    s = 1 << k
    lev = node_level(u)
    if (u >> (lev - 1)) == 2:
        ax, ay, lx, ly, rx, ry = 0, 0, s, 0, 0, s
    else:
        ax, ay, lx, ly, rx, ry = s, s, 0, s, s, 0
    for b in range(lev - 2, -1, -1):
        mx = (lx + rx) // 2
        my = (ly + ry) // 2
        if (u >> b) & 1 == 0:
            ax, ay, lx, ly, rx, ry = mx, my, lx, ly, ax, ay
        else:
            ax, ay, lx, ly, rx, ry = mx, my, ax, ay, rx, ry
    return ax, ay, lx, ly, rx, ry


@njit(cache=True)
def tree_mates(k: int) -> np.ndarray:
    """mate (2^(2k+2),) int32 of every node (0: hypotenuse on the domain border).

    Same-level neighbours (B across the hypotenuse, NL across a–l, NR across a–r) pass from a
    node to its children: child 2u gets B = NL.(2·+1), NL = B.(2·+1), NR = 2u + 1; child
    2u + 1 gets B = NR.(2·), NL = 2u, NR = B.(2·) (0 stays 0).
    """
    top = 2 * k + 1
    mate = np.zeros(1 << (top + 1), dtype=np.int32)
    b = np.array([3, 2], dtype=np.int64)
    nl = np.zeros(2, dtype=np.int64)
    nr = np.zeros(2, dtype=np.int64)
    mate[2] = 3
    mate[3] = 2
    for lev in range(1, top):
        first = 1 << lev
        cnt = first
        b2 = np.empty(2 * cnt, dtype=np.int64)
        nl2 = np.empty(2 * cnt, dtype=np.int64)
        nr2 = np.empty(2 * cnt, dtype=np.int64)
        for i in range(cnt):
            u = first + i
            bu, lu, ru = b[i], nl[i], nr[i]
            j = 2 * i
            b2[j] = 2 * lu + 1 if lu else 0
            nl2[j] = 2 * bu + 1 if bu else 0
            nr2[j] = 2 * u + 1
            b2[j + 1] = 2 * ru if ru else 0
            nl2[j + 1] = 2 * u
            nr2[j + 1] = 2 * bu if bu else 0
            mate[2 * u] = b2[j]
            mate[2 * u + 1] = b2[j + 1]
        b, nl, nr = b2, nl2, nr2
    return mate


@njit(cache=True, inline="always")
def _on_border(ux, uy, vx, vy, s) -> bool:
    return (ux == vx and (ux == 0 or ux == s)) or (uy == vy and (uy == 0 or uy == s))


@njit(cache=True)
def _tri_sse(heights, s, ax, ay, lx, ly, rx, ry) -> float:
    """d(u): weighted sum of squared errors of the grid points of one triangle (see module)."""
    if orient(ax, ay, lx, ly, rx, ry) < 0:
        lx, ly, rx, ry = rx, ry, lx, ly
    za = float(heights[ay, ax])
    zl = float(heights[ly, lx])
    zr = float(heights[ry, rx])
    den = float(orient(ax, ay, lx, ly, rx, ry))
    # Weights of points on each edge: 1/2 inside the domain, 1 on its border.
    w_al = 1.0 if _on_border(ax, ay, lx, ly, s) else 0.5
    w_lr = 1.0 if _on_border(lx, ly, rx, ry, s) else 0.5
    w_ra = 1.0 if _on_border(rx, ry, ax, ay, s) else 0.5
    total = 0.0
    y0 = min(ay, min(ly, ry))
    y1 = max(ay, max(ly, ry))
    for y in range(y0, y1 + 1):
        lo, hi = row_span(ax, ay, lx, ly, rx, ry, y)
        row = heights[y]
        for x in range(lo, hi + 1):
            o_lr = orient(lx, ly, rx, ry, x, y)
            o_ra = orient(rx, ry, ax, ay, x, y)
            o_al = orient(ax, ay, lx, ly, x, y)
            e = row[x] - (o_lr * za + o_ra * zl + o_al * zr) / den
            w = 1.0
            zeros = (o_lr == 0) + (o_ra == 0) + (o_al == 0)
            if zeros >= 2:
                continue  # a corner: exact
            if o_lr == 0:
                w = w_lr
            elif o_ra == 0:
                w = w_ra
            elif o_al == 0:
                w = w_al
            total += w * e * e
    return total


@njit(cache=True, inline="always")
def _put(stack, i, u, ax, ay, lx, ly, rx, ry) -> None:
    stack[i, 0] = u
    stack[i, 1] = ax
    stack[i, 2] = ay
    stack[i, 3] = lx
    stack[i, 4] = ly
    stack[i, 5] = rx
    stack[i, 6] = ry


@njit(cache=True)
def tree_distortions(heights: np.ndarray, k: int) -> np.ndarray:
    """d (2^(2k+2),) float64 of every node (d[0] = d[1] = 0; unit triangles are exact)."""
    s = 1 << k
    top = 2 * k + 1
    d = np.zeros(1 << (top + 1), dtype=np.float64)
    # Depth-first with the corners on an explicit stack; unit triangles (level top) are skipped.
    stack = np.empty((2 * top + 4, 7), dtype=np.int64)
    _put(stack, 0, 2, 0, 0, s, 0, 0, s)
    _put(stack, 1, 3, s, s, 0, s, s, 0)
    sp = 2
    while sp > 0:
        sp -= 1
        u = stack[sp, 0]
        ax, ay, lx, ly, rx, ry = (
            stack[sp, 1],
            stack[sp, 2],
            stack[sp, 3],
            stack[sp, 4],
            stack[sp, 5],
            stack[sp, 6],
        )
        d[u] = _tri_sse(heights, s, ax, ay, lx, ly, rx, ry)
        if node_level(u) + 1 < top:
            mx = (lx + rx) // 2
            my = (ly + ry) // 2
            _put(stack, sp, 2 * u, mx, my, lx, ly, ax, ay)
            _put(stack, sp + 1, 2 * u + 1, mx, my, ax, ay, rx, ry)
            sp += 2
    return d


@njit(cache=True)
def tree_gains(d: np.ndarray, k: int) -> np.ndarray:
    """gain (2^(2k+1),) float64: d(u) − d(2u) − d(2u + 1) for every splittable node."""
    n = 1 << (2 * k + 1)
    g = np.zeros(n, dtype=np.float64)
    for u in range(2, n):
        g[u] = d[u] - d[2 * u] - d[2 * u + 1]
    return g


# -- refinement: greedy tree growing --------------------------------------------------------


@njit(cache=True)
def _split_domain(t, mate, birth, step, gain, out):
    """Fill ``out`` with the splitting domain of leaf t (finest first); returns (count, gain)."""
    n = 0
    g = 0.0
    x = t
    while True:
        out[n] = x
        n += 1
        g += gain[x]
        m = mate[x]
        if m == 0:
            break
        out[n] = m
        n += 1
        g += gain[m]
        p = m >> 1
        if birth[p] < step:
            break
        x = p
    return n, g


@njit(cache=True)
def subtree_slopes(d: np.ndarray, k: int) -> np.ndarray:
    """best (2^(2k+1),) float64: for every node t, the largest distortion removed per added
    triangle when t's subtree is split completely down to some depth δ >= 1,
    max over δ of (d(t) − Σ d(descendants at depth δ)) / (2^δ − 1). O(n) in place.
    """
    nsplit = 1 << (2 * k + 1)
    s = d.copy()
    best = np.full(nsplit, -np.inf)
    limit = s.shape[0]
    cnt = 1.0
    while limit > 2:
        half = limit // 2
        # Ascending t: s[2t], s[2t + 1] still hold depth δ − 1 when s[t] becomes depth δ.
        for t in range(1, half):
            s[t] = s[2 * t] + s[2 * t + 1]
            if t >= 2:
                best[t] = max(best[t], (d[t] - s[t]) / cnt)
        cnt = 2.0 * cnt + 1.0
        limit = half
    return best


@njit(cache=True, inline="always")
def _priority(t, n, g, best) -> float:
    """Refinement priority of leaf t: max(λ of its splitting domain, best subtree slope).

    The distortion is not monotonic: splitting a large triangle may raise it while splitting
    its descendants lowers it a lot, so the plain λ = g / n would never choose it.
    """
    return max(g / n, best[t])


@njit(cache=True)
def refine_kernel(
    gain: np.ndarray, mate: np.ndarray, best: np.ndarray, d_root: float, k: int, max_rate: int
):
    """Greedy growing from the two root triangles: split the leaf (with its splitting domain)
    of largest λ (distortion removed per triangle added, see ``_priority``), until
    ``max_rate`` triangles or the full grid.

    Returns (birth (2^(2k+2),) int32 step at which each node splits (NEVER if not),
    rates (S+1,) int64, distortions (S+1,) float64) for meshes 0..S.
    """
    top = 2 * k + 1
    nn = 1 << (top + 1)
    nsplit = 1 << top  # nodes below this id can split
    birth = np.full(nn, NEVER, dtype=np.int32)
    birth[1] = -1
    pos = np.full(nsplit, -1, dtype=np.int32)
    heap = np.empty(nsplit, dtype=np.int32)
    hkey = np.empty(nsplit, dtype=np.float64)
    size = 0
    buf = np.empty(4 * top + 8, dtype=np.int64)
    stack = np.empty(64, dtype=np.int64)
    rates = [2]
    dist = [d_root]
    step = 0  # meshes done so far; nodes with birth < step + 1 are internal after this step
    # λ of a leaf, evaluated against the mesh after the current step.
    for t in (2, 3):
        if t < nsplit:
            n, g = _split_domain(t, mate, birth, 0, gain, buf)
            size = heap_push(heap, hkey, pos, size, t, _priority(t, n, g, best))
    rate = 2
    cur = d_root
    while size > 0 and (max_rate <= 0 or rate < max_rate):
        t = heap[0]
        n, g = _split_domain(t, mate, birth, step, gain, buf)
        # Coarsest first, so every split has an internal parent.
        for i in range(n - 1, -1, -1):
            u = buf[i]
            birth[u] = step
            size = heap_remove(heap, hkey, pos, size, u)
        step += 1
        rate += n
        cur -= g
        rates.append(rate)
        dist.append(cur)
        # New leaves, and leaves whose splitting domain ran through a split node.
        sp = 0
        for i in range(n):
            u = buf[i]
            for c in (2 * u, 2 * u + 1):
                if c < nsplit and birth[c] >= step:
                    if sp + 2 > stack.shape[0]:
                        stack = _grow(stack)
                    stack[sp] = c
                    sp += 1
                    y = mate[c]
                    if y != 0 and birth[y >> 1] < step and birth[y] >= step:
                        stack[sp] = y
                        sp += 1
        while sp > 0:
            sp -= 1
            y = stack[sp]
            nn2, g2 = _split_domain(y, mate, birth, step, gain, buf[n:])
            if pos[y] >= 0:
                size = heap_update(heap, hkey, pos, size, y, _priority(y, nn2, g2, best))
            else:
                size = heap_push(heap, hkey, pos, size, y, _priority(y, nn2, g2, best))
            # Leaves across the hypotenuses of y's (absent) children pass through y.
            if 2 * y < nsplit:
                for c in (2 * y, 2 * y + 1):
                    z = mate[c]
                    if z != 0 and z < nsplit and birth[z >> 1] < step and birth[z] >= step:
                        if sp + 1 > stack.shape[0]:
                            stack = _grow(stack)
                        stack[sp] = z
                        sp += 1
    return birth, np.array(rates, dtype=np.int64), np.array(dist, dtype=np.float64)


@njit(cache=True)
def _grow(a):
    out = np.empty(2 * a.shape[0], dtype=a.dtype)
    out[: a.shape[0]] = a
    return out


# -- decimation: constrained G-BFOS ---------------------------------------------------------


@njit(cache=True)
def merge_roots(t, mate, alive, mark, qid, out):
    """Roots of the merging domain of internal node t (``alive`` marks the internal nodes).

    Breadth-first from t over the candidates of every found node (its mate and its children's
    mates); a candidate inside a found subtree is skipped. mark: (nodes,) int64 scratch, qid a
    value not yet in it. Fills ``out`` (grown when full) and returns (out, n): the maximal found
    nodes first, absorbed ones dropped.
    """
    out[0] = t
    mark[t] = qid
    n = 1
    head = 0
    while head < n:
        r = out[head]
        head += 1
        for j in range(3):
            c = mate[r] if j == 0 else mate[2 * r + j - 1]
            if c == 0 or not alive[c]:
                continue
            a = c
            covered = False
            while a >= 2:
                if mark[a] == qid:
                    covered = True
                    break
                a >>= 1
            if covered:
                continue
            mark[c] = qid
            if n == out.shape[0]:
                out = _grow(out)
            out[n] = c
            n += 1
    # Keep the maximal ones: no found proper ancestor.
    m = 0
    for i in range(n):
        a = out[i] >> 1
        inside = False
        while a >= 2:
            if mark[a] == qid:
                inside = True
                break
            a >>= 1
        if not inside:
            out[m] = out[i]
            m += 1
    return out, m


@njit(cache=True)
def split_closure(t, mate, alive=None):
    """Nodes that must be split for t to be split: t closed under parent and mate links.

    alive: restrict to these nodes (None: the full tree). Returns (c,) int64, t first.
    """
    seen = dict()
    out = [t]
    seen[t] = True
    head = 0
    while head < len(out):
        x = out[head]
        head += 1
        for y in (x >> 1, np.int64(mate[x])):
            if y >= 2 and y not in seen and (alive is None or alive[y]):
                seen[y] = True
                out.append(y)
    return np.array(out, dtype=np.int64)


@njit(cache=True)
def decimate_kernel(gain: np.ndarray, mate: np.ndarray, d_root: float, k: int, min_rate: int):
    """Constrained G-BFOS from the full tree down to ``min_rate`` triangles (>= 2).

    Each step prunes the internal node t of smallest λ = Δd / Δr together with its merging
    domain P(t) (Δd the distortion added, Δr the triangles removed). Every internal x keeps
    the sums of P(x) (pd: Σ gain, pn: count); after a prune P(x) loses exactly the subtrees of
    the roots ρ of P(t) that lie in it, i.e. those with x in the split closure of ρ, so the
    update walks those closures (O(depth) each) and re-keys the heap there.

    Returns (birth (2^(2k+2),) int32, rates (S+1,) int64, distortions (S+1,) float64) indexed
    coarse to fine: mesh j splits the nodes with birth < j.
    """
    top = 2 * k + 1
    nn = 1 << (top + 1)
    nsplit = 1 << top
    alive = np.zeros(nn, dtype=np.bool_)
    alive[1:nsplit] = True
    # Subtree sums over internal nodes: count and Σ gain (= distortion added by pruning it).
    cnt = np.zeros(nsplit, dtype=np.int64)
    dsum = np.zeros(nsplit, dtype=np.float64)
    for u in range(nsplit - 1, 1, -1):
        c = 1
        g = gain[u]
        if 2 * u < nsplit:
            c += cnt[2 * u] + cnt[2 * u + 1]
            g += dsum[2 * u] + dsum[2 * u + 1]
        cnt[u] = c
        dsum[u] = g
    mark = np.zeros(nn, dtype=np.int64)
    qid = 0
    roots = np.empty(256, dtype=np.int64)
    # Sums over P(x) of every internal node, and the min-heap of λ (negated in a max-heap).
    pd = np.zeros(nsplit, dtype=np.float64)
    pn = np.zeros(nsplit, dtype=np.int64)
    pos = np.full(nsplit, -1, dtype=np.int32)
    heap = np.empty(nsplit, dtype=np.int32)
    hkey = np.empty(nsplit, dtype=np.float64)
    size = 0
    # A node and its mate share P, so one of them (the smaller id) stands for both.
    for u in range(2, nsplit):
        m = mate[u]
        if m != 0 and m < u:
            pd[u] = pd[m]
            pn[u] = pn[m]
            continue
        qid += 1
        roots, n = merge_roots(u, mate, alive, mark, qid, roots)
        for i in range(n):
            pd[u] += dsum[roots[i]]
            pn[u] += cnt[roots[i]]
        size = heap_push(heap, hkey, pos, size, u, -pd[u] / pn[u])
    rate = nsplit
    cur = d_root - dsum[2] - dsum[3]
    rates = [rate]
    dist = [cur]
    pruned_at = np.full(nn, -1, dtype=np.int64)
    sub = np.empty(2 * top + 8, dtype=np.int64)
    queue = np.empty(1024, dtype=np.int64)
    plist = np.empty(1024, dtype=np.int64)
    tlist = np.empty(1024, dtype=np.int64)
    inp = np.zeros(nsplit, dtype=np.int64)
    touched = np.zeros(nsplit, dtype=np.int64)
    rd = np.empty(256, dtype=np.float64)
    rn = np.empty(256, dtype=np.int64)
    step = 0
    while size > 0 and rate > max(min_rate, 2):
        t = heap[0]
        qid += 1
        roots, n = merge_roots(t, mate, alive, mark, qid, roots)
        if rd.shape[0] < n:
            rd = np.empty(roots.shape[0], dtype=np.float64)
            rn = np.empty(roots.shape[0], dtype=np.int64)
        dr = 0
        dd = 0.0
        for i in range(n):
            rd[i] = dsum[roots[i]]
            rn[i] = cnt[roots[i]]
            dr += rn[i]
            dd += rd[i]
        # 1. P(t): the roots' internal subtrees (marked with this step).
        pn_t = 0
        for i in range(n):
            sub[0] = roots[i]
            sp = 1
            while sp > 0:
                sp -= 1
                u = sub[sp]
                if u >= nsplit or not alive[u] or inp[u] == step + 1:
                    continue
                inp[u] = step + 1
                if pn_t == plist.shape[0]:
                    plist = _grow(plist)
                plist[pn_t] = u
                pn_t += 1
                sub[sp] = 2 * u
                sub[sp + 1] = 2 * u + 1
                sp += 2
        # 2. Every surviving x with u in P(x), i.e. x in the split closure of u, loses u. A
        #    node and its mate have the same closure (and are pruned together): walk it once.
        tn = 0
        for q in range(pn_t):
            u = plist[q]
            mu = mate[u]
            if mu != 0 and mu < u:
                continue
            gu = gain[u] + (gain[mu] if mu != 0 else 0.0)
            nu = 2 if mu != 0 else 1
            qid += 1
            queue[0] = u
            mark[u] = qid
            qn = 1
            head = 0
            while head < qn:
                x = queue[head]
                head += 1
                for y in (x >> 1, np.int64(mate[x])):
                    if y >= 2 and alive[y] and mark[y] != qid:
                        mark[y] = qid
                        if qn == queue.shape[0]:
                            queue = _grow(queue)
                        queue[qn] = y
                        qn += 1
                        if inp[y] != step + 1:
                            pd[y] -= gu
                            pn[y] -= nu
                            if touched[y] != step + 1:
                                touched[y] = step + 1
                                if tn == tlist.shape[0]:
                                    tlist = _grow(tlist)
                                tlist[tn] = y
                                tn += 1
        # 3. Ancestors of every root lose the root's subtree sums.
        for i in range(n):
            a = roots[i] >> 1
            while a >= 2:
                cnt[a] -= rn[i]
                dsum[a] -= rd[i]
                a >>= 1
        # 4. The roots' internal subtrees leave the mesh (and the heap).
        for i in range(n):
            sub[0] = roots[i]
            sp = 1
            while sp > 0:
                sp -= 1
                u = sub[sp]
                if u >= nsplit or not alive[u]:
                    continue
                alive[u] = False
                pruned_at[u] = step
                size = heap_remove(heap, hkey, pos, size, u)
                sub[sp] = 2 * u
                sub[sp + 1] = 2 * u + 1
                sp += 2
        rate -= dr
        cur += dd
        rates.append(rate)
        dist.append(cur)
        for q in range(tn):
            x = tlist[q]
            if pos[x] >= 0:
                size = heap_update(heap, hkey, pos, size, x, -pd[x] / pn[x])
        step += 1
    # Coarse-to-fine birth: mesh j (j = S − prunes done) splits nodes with birth < j.
    total = step
    birth = np.full(nn, NEVER, dtype=np.int32)
    birth[1] = -1
    for u in range(2, nsplit):
        if alive[u]:
            birth[u] = -1
        else:
            birth[u] = total - 1 - pruned_at[u]
    r = np.array(rates, dtype=np.int64)[::-1].copy()
    dd_out = np.array(dist, dtype=np.float64)[::-1].copy()
    return birth, r, dd_out


# -- meshes of a sequence -------------------------------------------------------------------


@njit(cache=True)
def cut_leaves(birth: np.ndarray, j: int, k: int):
    """Leaves of mesh j (nodes whose parent has birth < j and that do not): (m,) int64 ids."""
    top = 2 * k + 1
    nsplit = 1 << top
    out = np.empty(1024, dtype=np.int64)
    n = 0
    stack = np.empty(4 * top + 8, dtype=np.int64)
    stack[0] = 3
    stack[1] = 2
    sp = 2
    while sp > 0:
        sp -= 1
        u = stack[sp]
        if u < nsplit and birth[u] < j:
            stack[sp] = 2 * u + 1
            stack[sp + 1] = 2 * u
            sp += 2
        else:
            if n == out.shape[0]:
                out = _grow(out)
            out[n] = u
            n += 1
    return out[:n].copy()


@njit(cache=True)
def leaf_mesh(leaves: np.ndarray, k: int, rows: int, cols: int):
    """Vertices and triangles of a set of tree triangles.

    Returns (vx (n,), vy (n,) int64 lattice column and row, tv (m, 3) int64 counter-clockwise
    in (column, row)).
    """
    mark = np.full(rows * cols, -1, dtype=np.int64)
    vx = np.empty(3 * leaves.shape[0], dtype=np.int64)
    vy = np.empty(3 * leaves.shape[0], dtype=np.int64)
    tv = np.empty((leaves.shape[0], 3), dtype=np.int64)
    nv = 0
    for i in range(leaves.shape[0]):
        ax, ay, lx, ly, rx, ry = node_corners(leaves[i], k)
        if orient(ax, ay, lx, ly, rx, ry) < 0:
            lx, ly, rx, ry = rx, ry, lx, ly
        for c in range(3):
            px, py = (ax, ay) if c == 0 else ((lx, ly) if c == 1 else (rx, ry))
            key = py * cols + px
            if mark[key] < 0:
                mark[key] = nv
                vx[nv] = px
                vy[nv] = py
                nv += 1
            tv[i, c] = mark[key]
    return vx[:nv].copy(), vy[:nv].copy(), tv


@njit(cache=True)
def mesh_errors(heights: np.ndarray, vx: np.ndarray, vy: np.ndarray, tv: np.ndarray):
    """Exact errors of a lattice mesh over every grid point: (sse, max error, points covered).

    vx, vy (n,) int64 lattice column and row of the vertices; tv (m, 3) int64 triangles. Each
    grid point is counted once, against the first triangle that holds it; points outside
    every triangle are not counted (compare the count with the grid's size).
    """
    rows, cols = heights.shape
    seen = np.zeros(rows * cols, dtype=np.bool_)
    sse = 0.0
    emax = 0.0
    count = 0
    for i in range(tv.shape[0]):
        a, b, c = tv[i, 0], tv[i, 1], tv[i, 2]
        ax, ay, bx, by, cx, cy = vx[a], vy[a], vx[b], vy[b], vx[c], vy[c]
        if orient(ax, ay, bx, by, cx, cy) < 0:
            bx, by, cx, cy = cx, cy, bx, by
        den = float(orient(ax, ay, bx, by, cx, cy))
        if den == 0.0:
            continue
        za = float(heights[ay, ax])
        zb = float(heights[by, bx])
        zc = float(heights[cy, cx])
        y0 = min(ay, min(by, cy))
        y1 = max(ay, max(by, cy))
        for y in range(y0, y1 + 1):
            lo, hi = row_span(ax, ay, bx, by, cx, cy, y)
            for x in range(lo, hi + 1):
                key = y * cols + x
                if seen[key]:
                    continue
                seen[key] = True
                count += 1
                w_a = orient(bx, by, cx, cy, x, y)
                w_b = orient(cx, cy, ax, ay, x, y)
                w_c = orient(ax, ay, bx, by, x, y)
                e = heights[y, x] - (w_a * za + w_b * zb + w_c * zc) / den
                sse += e * e
                emax = max(emax, abs(e))
    return sse, emax, count
