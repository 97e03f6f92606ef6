//! Minimum-cost one-to-one assignment (the Hungarian method's shortest augmenting paths).
//!
//! Not a thesis equation: the thesis tracked one object per window and never had to decide
//! which blob belongs to which track. Several targets need a global assignment — a greedy
//! nearest match hands one blob to two tracks or swaps identities at crossings.

/// Assigns rows to columns minimising the total cost. `cost[r][c]` may be `f64::INFINITY`
/// (not allowed). Returns, for each row, the chosen column or `None`. Feasible pairs come
/// first: no assignment leaves a feasible pair out to lower the cost.
pub fn assign_min_cost(cost: &[Vec<f64>]) -> Vec<Option<usize>> {
    let rows = cost.len();
    let cols = cost.iter().map(|r| r.len()).max().unwrap_or(0);
    let mut flat = vec![f64::INFINITY; rows * cols];
    for (r, row) in cost.iter().enumerate() {
        flat[r * cols..r * cols + row.len()].copy_from_slice(row);
    }
    let mut a = Assigner::default();
    a.solve(&flat, rows, cols).to_vec()
}

/// The first column of `row` with the least finite cost (in `f64::total_cmp`'s order), if any.
#[inline]
pub fn cheapest_allowed(row: &[f64]) -> Option<usize> {
    let mut best = f64::INFINITY;
    let mut at = None;
    for (c, &v) in row.iter().enumerate() {
        if v.is_finite() && v.total_cmp(&best).is_lt() {
            best = v;
            at = Some(c);
        }
    }
    at
}

/// The common case while tracking: no two rows of the `rows × cols` matrix have the same
/// cheapest allowed column. Each row then takes its own: every row that can have a column has
/// one, each at its least cost, so no assignment has more pairs or a lower total. Writes that
/// into `out` (all `None` on entry, left so when this is not the case) and says whether it was.
fn each_its_cheapest(
    cost: &[f64],
    rows: usize,
    cols: usize,
    used: &mut Vec<bool>,
    out: &mut [Option<usize>],
) -> bool {
    used.clear();
    used.resize(cols, false);
    for r in 0..rows {
        if let Some(c) = cheapest_allowed(&cost[r * cols..(r + 1) * cols]) {
            if used[c] {
                out.fill(None);
                return false;
            }
            used[c] = true;
            out[r] = Some(c);
        }
    }
    true
}

/// The cost of leaving a row unassigned in a `rows × cols` matrix: above any sum of its
/// allowed costs, so the most pairs come before the least total.
fn unassigned_cost(cost: &[f64], rows: usize, cols: usize) -> f64 {
    let finite_max = cost
        .iter()
        .filter(|c| c.is_finite())
        .fold(0.0f64, |a, &c| a.max(c.abs()));
    (finite_max + 1.0) * (rows.max(cols) as f64 + 1.0) * 4.0
}

/// The assignment solver with its buffers, reusable without allocating per call.
#[derive(Debug, Default, Clone)]
pub struct Assigner {
    /// Potentials of the rows and of the columns (real `0..cols`, then each row's own
    /// "unassigned" column).
    u: Vec<f64>,
    v: Vec<f64>,
    /// Per column: its shortest distance in this search, the row it was reached from, whether
    /// it is settled, and the row assigned to it.
    dist: Vec<f64>,
    from: Vec<usize>,
    done: Vec<bool>,
    col_row: Vec<usize>,
    /// Per row: its column.
    row_col: Vec<usize>,
    /// Columns reached in this search (settled or not), and those not yet settled.
    touched: Vec<usize>,
    reached: Vec<usize>,
    used: Vec<bool>,
    out: Vec<Option<usize>>,
}

/// No row or column.
const NONE: usize = usize::MAX;

impl Assigner {
    /// Solves for a row-major `rows × cols` cost matrix (`INFINITY` = not allowed).
    pub fn solve(&mut self, cost: &[f64], rows: usize, cols: usize) -> &[Option<usize>] {
        self.out.clear();
        self.out.resize(rows, None);
        if rows == 0 || cols == 0 || cost.len() < rows * cols {
            return &self.out;
        }
        if !each_its_cheapest(cost, rows, cols, &mut self.used, &mut self.out) {
            self.solve_sparse(cost, rows, cols);
        }
        &self.out
    }

    /// The general case, into `out` (all `None` on entry): the Hungarian method's shortest
    /// augmenting paths (Dijkstra's search on costs reduced by potentials), each row also
    /// having a column of its own at a cost `big` above any sum of allowed costs — taking it
    /// is leaving the row unassigned. So the most rows are assigned, then the least total
    /// cost, as on the textbook method's padded square matrix. Two things make it cheap on
    /// tracking's matrices, where it runs when two tracks want one blob (two markers merged
    /// in the image, a lost track's window grown over the others'): it starts from each row at
    /// its cheapest column where no earlier row took that column (row potentials at each
    /// row's least cost make those pairs tight and no reduced cost negative, so the method's
    /// invariant holds), and searches only from the rows left, one or two; and a search
    /// follows only allowed pairs from the columns it settles.
    fn solve_sparse(&mut self, cost: &[f64], rows: usize, cols: usize) {
        let big = unassigned_cost(cost, rows, cols);
        // Columns 0..cols, then row r's own at cols + r.
        let all = cols + rows;
        self.v.clear();
        self.v.resize(all, 0.0);
        self.col_row.clear();
        self.col_row.resize(all, NONE);
        self.row_col.clear();
        self.row_col.resize(rows, NONE);
        self.dist.clear();
        self.dist.resize(all, f64::INFINITY);
        self.from.clear();
        self.from.resize(all, NONE);
        self.done.clear();
        self.done.resize(all, false);
        // Each row's least cost (its own column's `big` when it has no allowed one) as its
        // potential, and its cheapest column taken when still free.
        self.u.clear();
        for r in 0..rows {
            let row = &cost[r * cols..(r + 1) * cols];
            let (c, least) = match cheapest_allowed(row) {
                Some(c) => (c, row[c]),
                None => (cols + r, big),
            };
            self.u.push(least);
            if self.col_row[c] == NONE {
                self.col_row[c] = r;
                self.row_col[r] = c;
            }
        }
        for start in 0..rows {
            if self.row_col[start] != NONE {
                continue;
            }
            self.reached.clear();
            self.touched.clear();
            // The columns of a row `r` whose own distance is `d`, relaxed.
            let relax = |r: usize, d: f64, s: &mut Self| {
                let ur = s.u[r];
                let row = &cost[r * cols..(r + 1) * cols];
                let own = cols + r;
                for (c, &cv) in row.iter().enumerate().chain([(own, &big)]) {
                    if !cv.is_finite() || s.done[c] {
                        continue;
                    }
                    let nd = d + (cv - ur - s.v[c]);
                    if nd < s.dist[c] {
                        if s.dist[c] == f64::INFINITY {
                            s.reached.push(c);
                            s.touched.push(c);
                        }
                        s.dist[c] = nd;
                        s.from[c] = r;
                    }
                }
            };
            relax(start, 0.0, self);
            // Settle the nearest reached column until a free one (the start row's own column
            // is always free, so one is found).
            let mut end = NONE;
            let mut delta = 0.0;
            while let Some((k, &c)) = self
                .reached
                .iter()
                .enumerate()
                .min_by(|a, b| self.dist[*a.1].total_cmp(&self.dist[*b.1]))
            {
                self.reached.swap_remove(k);
                self.done[c] = true;
                let d = self.dist[c];
                match self.col_row[c] {
                    NONE => {
                        (end, delta) = (c, d);
                        break;
                    }
                    r => relax(r, d, self),
                }
            }
            if end == NONE {
                break;
            }
            // Potentials: settled columns and their rows by how much nearer than the end they
            // are (the path's pairs become tight, no reduced cost negative).
            self.u[start] += delta;
            for &c in &self.touched {
                if self.done[c] && c != end {
                    let gain = delta - self.dist[c];
                    self.v[c] -= gain;
                    self.u[self.col_row[c]] += gain;
                }
            }
            // Flip the path.
            let mut c = end;
            while c != NONE {
                let r = self.from[c];
                let next = self.row_col[r];
                self.row_col[r] = c;
                self.col_row[c] = r;
                c = if r == start { NONE } else { next };
            }
            // Reset what this search touched.
            for &c in &self.touched {
                self.dist[c] = f64::INFINITY;
                self.done[c] = false;
            }
        }
        for (r, &c) in self.row_col.iter().enumerate() {
            if c < cols && cost[r * cols + c].is_finite() {
                self.out[r] = Some(c);
            }
        }
    }
}

/// The assignment of a sparse problem given as its allowed pairs `(row, column, cost)` (rows
/// `< rows`, columns `< cols`; a pair given twice keeps its least cost): for each row, its
/// column or `None`. The pairs split into groups that share no row or column (connected
/// components); each group is solved on its own dense matrix, so the work follows the pairs
/// given, not `rows × cols` — a dense scene's thousand points each near one or two blobs is
/// a thousand small problems. The same optimum as [`Assigner::solve`] on the whole matrix:
/// no pair links two groups.
pub fn assign_sparse(
    pairs: &[(usize, usize, f64)],
    rows: usize,
    cols: usize,
    assigner: &mut Assigner,
) -> Vec<Option<usize>> {
    let mut out = vec![None; rows];
    // Union-find over rows (0..rows) and columns (rows..rows + cols).
    let mut parent: Vec<usize> = (0..rows + cols).collect();
    fn root(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let ok = |&&(r, c, v): &&(usize, usize, f64)| r < rows && c < cols && v.is_finite();
    for &(r, c, _) in pairs.iter().filter(ok) {
        let (a, b) = (root(&mut parent, r), root(&mut parent, rows + c));
        if a != b {
            parent[a] = b;
        }
    }
    // Each group's rows and columns, in order.
    let mut group_of: Vec<usize> = vec![usize::MAX; rows + cols];
    let mut groups: Vec<(Vec<usize>, Vec<usize>)> = Vec::new();
    let mut slot = vec![usize::MAX; rows + cols];
    for &(r, c, _) in pairs.iter().filter(ok) {
        let g = root(&mut parent, r);
        if group_of[g] == usize::MAX {
            group_of[g] = groups.len();
            groups.push((Vec::new(), Vec::new()));
        }
        let k = group_of[g];
        if slot[r] == usize::MAX {
            slot[r] = groups[k].0.len();
            groups[k].0.push(r);
        }
        if slot[rows + c] == usize::MAX {
            slot[rows + c] = groups[k].1.len();
            groups[k].1.push(c);
        }
    }
    let mut costs: Vec<Vec<f64>> = groups
        .iter()
        .map(|(r, c)| vec![f64::INFINITY; r.len() * c.len()])
        .collect();
    for &(r, c, v) in pairs.iter().filter(ok) {
        let k = group_of[root(&mut parent, r)];
        let w = groups[k].1.len();
        let e = &mut costs[k][slot[r] * w + slot[rows + c]];
        if v < *e {
            *e = v;
        }
    }
    for (k, (rs, cs)) in groups.iter().enumerate() {
        if let ([r], [c]) = (rs.as_slice(), cs.as_slice()) {
            out[*r] = Some(*c);
            continue;
        }
        for (i, col) in assigner
            .solve(&costs[k], rs.len(), cs.len())
            .iter()
            .enumerate()
        {
            out[rs[i]] = col.map(|j| cs[j]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(cost: &[Vec<f64>]) -> f64 {
        // Best total over all partial injections rows → cols (small sizes only).
        fn go(
            r: usize,
            cost: &[Vec<f64>],
            used: &mut Vec<bool>,
            acc: f64,
            count: usize,
            best: &mut (usize, f64),
        ) {
            if r == cost.len() {
                if count > best.0 || (count == best.0 && acc < best.1) {
                    *best = (count, acc);
                }
                return;
            }
            go(r + 1, cost, used, acc, count, best);
            for c in 0..cost[r].len() {
                if !used[c] && cost[r][c].is_finite() {
                    used[c] = true;
                    go(r + 1, cost, used, acc + cost[r][c], count + 1, best);
                    used[c] = false;
                }
            }
        }
        let mut best = (0usize, f64::INFINITY);
        let cols = cost.iter().map(|r| r.len()).max().unwrap_or(0);
        go(0, cost, &mut vec![false; cols], 0.0, 0, &mut best);
        best.1
    }

    #[test]
    fn sparse_pairs_give_the_dense_optimum() {
        let mut rng = crate::SplitMix64::new(11);
        let mut a = Assigner::default();
        for round in 0..300 {
            let (rows, cols) = (
                1 + (rng.next_u64() % 9) as usize,
                1 + (rng.next_u64() % 9) as usize,
            );
            let density = [0.1, 0.3, 0.7][round % 3];
            let mut dense = vec![vec![f64::INFINITY; cols]; rows];
            let mut pairs = Vec::new();
            for (r, row) in dense.iter_mut().enumerate() {
                for (c, v) in row.iter_mut().enumerate() {
                    if rng.uniform() < density {
                        *v = (rng.uniform() * 10.0).round();
                        pairs.push((r, c, *v));
                    }
                }
            }
            let got = assign_sparse(&pairs, rows, cols, &mut a);
            let total: f64 = got
                .iter()
                .enumerate()
                .filter_map(|(r, c)| c.map(|c| dense[r][c]))
                .sum();
            let count = got.iter().flatten().count();
            let want = assign_min_cost(&dense);
            let want_total: f64 = want
                .iter()
                .enumerate()
                .filter_map(|(r, c)| c.map(|c| dense[r][c]))
                .sum();
            assert_eq!(count, want.iter().flatten().count(), "round {round}");
            assert!(
                (total - want_total).abs() < 1e-9,
                "round {round}: {total} {want_total}"
            );
            assert!((total - brute(&dense)).abs() < 1e-9, "round {round}");
            let mut cols_used: Vec<usize> = got.iter().flatten().copied().collect();
            cols_used.sort_unstable();
            cols_used.dedup();
            assert_eq!(cols_used.len(), count, "a column twice in round {round}");
        }
    }

    #[test]
    fn beats_greedy_and_matches_brute_force() {
        // Greedy would give row 0 column 0 (cost 1) and row 1 column 1 (cost 100).
        let cost = vec![vec![1.0, 2.0], vec![1.5, 100.0]];
        assert_eq!(assign_min_cost(&cost), vec![Some(1), Some(0)]);
        let mut rng = crate::SplitMix64::new(5);
        for trial in 0..200 {
            let (r, c) = (1 + (trial % 5), 1 + ((trial / 5) % 5));
            let cost: Vec<Vec<f64>> = (0..r)
                .map(|_| {
                    (0..c)
                        .map(|_| {
                            if rng.uniform() < 0.25 {
                                f64::INFINITY
                            } else {
                                rng.range(0.0, 50.0)
                            }
                        })
                        .collect()
                })
                .collect();
            let got = assign_min_cost(&cost);
            let mut seen = std::collections::HashSet::new();
            let mut total = 0.0;
            for (row, col) in got.iter().enumerate() {
                if let Some(col) = col {
                    assert!(seen.insert(*col), "column used twice");
                    total += cost[row][*col];
                }
            }
            assert!(
                (total - brute(&cost)).abs() < 1e-9 || (brute(&cost).is_infinite() && total == 0.0),
                "trial {trial}: {total} vs {}",
                brute(&cost)
            );
        }
    }

    /// Sparse matrices, as tracking makes them (most pairs gated out), small enough for
    /// brute force: the general method's answer is the optimum.
    #[test]
    fn sparse_matrices_get_the_optimum() {
        let mut rng = crate::SplitMix64::new(11);
        let mut split = 0;
        for trial in 0..400 {
            let (r, c) = (1 + (trial % 6), 1 + ((trial / 6) % 6));
            let density = [0.15, 0.3, 0.5][trial % 3];
            let cost: Vec<Vec<f64>> = (0..r)
                .map(|_| {
                    (0..c)
                        .map(|_| {
                            if rng.uniform() < density {
                                rng.range(0.0, 50.0)
                            } else {
                                f64::INFINITY
                            }
                        })
                        .collect()
                })
                .collect();
            // Two rows with the same cheapest column make the general method run rather than
            // the shortcut.
            let cheapest: Vec<usize> = cost
                .iter()
                .filter_map(|row| {
                    (0..row.len())
                        .filter(|&c| row[c].is_finite())
                        .min_by(|&a, &b| row[a].total_cmp(&row[b]))
                })
                .collect();
            split += (1..cheapest.len()).any(|i| cheapest[..i].contains(&cheapest[i])) as usize;
            let got = assign_min_cost(&cost);
            let mut seen = std::collections::HashSet::new();
            let (mut total, mut pairs) = (0.0, 0);
            for (row, col) in got.iter().enumerate() {
                if let Some(col) = col {
                    assert!(seen.insert(*col), "trial {trial}: column used twice");
                    total += cost[row][*col];
                    pairs += 1;
                }
            }
            let best = brute(&cost);
            assert!(
                (total - best).abs() < 1e-9 || (best.is_infinite() && pairs == 0),
                "trial {trial}: {total} vs {best}"
            );
        }
        assert!(split > 80, "{split} trials reached the general method");
    }

    /// The textbook Hungarian method on the padded square matrix (the solver before the
    /// sparse search), for the tests to check the sparse one's totals against at sizes
    /// brute force cannot reach.
    fn dense_reference(cost: &[f64], rows: usize, cols: usize) -> Vec<Option<usize>> {
        let n = rows.max(cols);
        let big = unassigned_cost(cost, rows, cols);
        let mut square = vec![big; n * n];
        for r in 0..rows {
            for c in 0..cols {
                if cost[r * cols + c].is_finite() {
                    square[r * n + c] = cost[r * cols + c];
                }
            }
        }
        let (mut u, mut v) = (vec![0.0; n + 1], vec![0.0; n + 1]);
        let (mut p, mut way) = (vec![0usize; n + 1], vec![0usize; n + 1]);
        for i in 1..=n {
            p[0] = i;
            let mut j0 = 0usize;
            let mut minv = vec![f64::INFINITY; n + 1];
            let mut used = vec![false; n + 1];
            loop {
                used[j0] = true;
                let i0 = p[j0];
                let (mut delta, mut j1) = (f64::INFINITY, 0usize);
                for j in 1..=n {
                    if used[j] {
                        continue;
                    }
                    let cur = square[(i0 - 1) * n + j - 1] - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
                for j in 0..=n {
                    if used[j] {
                        u[p[j]] += delta;
                        v[j] -= delta;
                    } else {
                        minv[j] -= delta;
                    }
                }
                j0 = j1;
                if p[j0] == 0 {
                    break;
                }
            }
            loop {
                let j1 = way[j0];
                p[j0] = p[j1];
                j0 = j1;
                if j0 == 0 {
                    break;
                }
            }
        }
        let mut out = vec![None; rows];
        for j in 1..=n {
            let i = p[j];
            if i >= 1 && i <= rows && j <= cols && cost[(i - 1) * cols + (j - 1)].is_finite() {
                out[i - 1] = Some(j - 1);
            }
        }
        out
    }

    /// (pairs, total cost) of an assignment, checking no column is used twice.
    fn score(cost: &[f64], cols: usize, got: &[Option<usize>]) -> (usize, f64) {
        let mut seen = std::collections::HashSet::new();
        let (mut pairs, mut total) = (0, 0.0);
        for (r, c) in got.iter().enumerate() {
            if let Some(c) = c {
                assert!(seen.insert(*c), "column {c} used twice");
                assert!(cost[r * cols + c].is_finite(), "a pair not allowed");
                pairs += 1;
                total += cost[r * cols + c];
            }
        }
        (pairs, total)
    }

    /// Tracking's matrices at tracking's sizes: up to 16 tracks, each allowed its own blob and
    /// sometimes a neighbour's, lost tracks allowed every blob, blobs missing (two markers
    /// merged) or extra, ties now and then: the sparse search gives as many pairs and the
    /// same total as the textbook method on the padded square matrix.
    #[test]
    fn the_sparse_search_equals_the_textbook_method_on_tracking_matrices() {
        let mut rng = crate::SplitMix64::new(23);
        let mut general = 0;
        for trial in 0..3000 {
            let rows = 1 + trial % 16;
            let cols = (rows as i64 + (trial / 16 % 5) as i64 - 2).max(1) as usize;
            let mut cost = vec![f64::INFINITY; rows * cols];
            for r in 0..rows {
                let lost = rng.uniform() < 0.15;
                for c in 0..cols {
                    let allowed = lost
                        || c == r
                        || (c as i64 - r as i64).abs() == 1 && rng.uniform() < 0.3
                        || rng.uniform() < 0.03;
                    if allowed {
                        cost[r * cols + c] = if rng.uniform() < 0.1 {
                            4.0
                        } else {
                            rng.range(0.0, 30.0).powi(2)
                        };
                    }
                }
            }
            let mut a = Assigner::default();
            let mut out = vec![None; rows];
            let mut used = Vec::new();
            general += !each_its_cheapest(&cost, rows, cols, &mut used, &mut out) as usize;
            let got = a.solve(&cost, rows, cols).to_vec();
            let want = dense_reference(&cost, rows, cols);
            let (gp, gt) = score(&cost, cols, &got);
            let (wp, wt) = score(&cost, cols, &want);
            assert_eq!(gp, wp, "trial {trial}: pairs");
            assert!(
                (gt - wt).abs() <= 1e-9 * wt.abs().max(1.0),
                "trial {trial}: {gt} vs {wt}"
            );
            // The same solver again (its buffers reused) gives the same.
            assert_eq!(
                a.solve(&cost, rows, cols),
                &got[..],
                "trial {trial}: reused"
            );
        }
        assert!(
            general > 1000,
            "{general} trials reached the general method"
        );
    }

    #[test]
    fn cheapest_allowed_is_the_first_least_finite_cost() {
        let mut rng = crate::SplitMix64::new(5);
        let pool = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -0.0,
            0.0,
            1.5,
            1.5,
            -2.0,
            3.0,
        ];
        for _ in 0..20_000 {
            let n = (rng.uniform() * 7.0) as usize;
            let row: Vec<f64> = (0..n)
                .map(|_| pool[(rng.uniform() * pool.len() as f64) as usize % pool.len()])
                .collect();
            let by_definition = (0..n)
                .filter(|&c| row[c].is_finite())
                .min_by(|&a, &b| row[a].total_cmp(&row[b]));
            assert_eq!(cheapest_allowed(&row), by_definition, "{row:?}");
        }
    }

    #[test]
    fn empty_inputs() {
        assert!(assign_min_cost(&[]).is_empty());
        assert_eq!(assign_min_cost(&[vec![], vec![]]), vec![None, None]);
    }
}
