//! Minimum-cost one-to-one assignment (the Hungarian method, O(n²·m)).
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

/// The assignment solver with its buffers, reusable without allocating per call.
#[derive(Debug, Default, Clone)]
pub struct Assigner {
    u: Vec<f64>,
    v: Vec<f64>,
    p: Vec<usize>,
    way: Vec<usize>,
    minv: Vec<f64>,
    used: Vec<bool>,
    out: Vec<Option<usize>>,
    /// Union-find over rows `0..rows` and columns `rows..rows + cols`: the components of the
    /// allowed pairs.
    parent: Vec<usize>,
    /// (component, row) and (component, column), sorted by component.
    members_r: Vec<(usize, usize)>,
    members_c: Vec<(usize, usize)>,
    /// One component's cost matrix and its solution.
    sub: Vec<f64>,
    sub_out: Vec<Option<usize>>,
    /// The Hungarian method's padded square matrix.
    square: Vec<f64>,
}

impl Assigner {
    /// Solves for a row-major `rows × cols` cost matrix (`INFINITY` = not allowed).
    pub fn solve(&mut self, cost: &[f64], rows: usize, cols: usize) -> &[Option<usize>] {
        self.out.clear();
        self.out.resize(rows, None);
        if rows == 0 || cols == 0 || cost.len() < rows * cols {
            return &self.out;
        }
        if each_its_cheapest(cost, rows, cols, &mut self.used, &mut self.out) {
            return &self.out;
        }
        // Rows and columns joined by no allowed pair never compete: each component of the
        // allowed pairs is solved on its own (a frame's tracks and blobs fall apart into small
        // groups, and the method is cubic in its matrix's size). The most pairs, then the
        // least cost, of the whole is the union of each component's.
        self.parent.clear();
        self.parent.extend(0..rows + cols);
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for r in 0..rows {
            for c in 0..cols {
                if cost[r * cols + c].is_finite() {
                    let (a, b) = (root(&mut self.parent, r), root(&mut self.parent, rows + c));
                    if a != b {
                        self.parent[a.max(b)] = a.min(b);
                    }
                }
            }
        }
        self.members_r.clear();
        self.members_c.clear();
        for r in 0..rows {
            let k = root(&mut self.parent, r);
            self.members_r.push((k, r));
        }
        for c in 0..cols {
            let k = root(&mut self.parent, rows + c);
            self.members_c.push((k, c));
        }
        self.members_r.sort_unstable();
        self.members_c.sort_unstable();
        let (members_r, members_c) = (
            std::mem::take(&mut self.members_r),
            std::mem::take(&mut self.members_c),
        );
        let mut sub = std::mem::take(&mut self.sub);
        let mut ci = 0;
        for group in members_r.chunk_by(|a, b| a.0 == b.0) {
            let k = group[0].0;
            while ci < members_c.len() && members_c[ci].0 < k {
                ci += 1;
            }
            let c_start = ci;
            while ci < members_c.len() && members_c[ci].0 == k {
                ci += 1;
            }
            let cs = &members_c[c_start..ci];
            if cs.is_empty() {
                continue; // a row with no allowed column
            }
            sub.clear();
            for &(_, r) in group {
                sub.extend(cs.iter().map(|&(_, c)| cost[r * cols + c]));
            }
            // A component whose rows have distinct cheapest columns (a track alone with its
            // blob, most of them) needs no more; the others run the general method.
            self.sub_out.clear();
            self.sub_out.resize(group.len(), None);
            if !each_its_cheapest(
                &sub,
                group.len(),
                cs.len(),
                &mut self.used,
                &mut self.sub_out,
            ) {
                self.solve_dense(&sub, group.len(), cs.len());
            }
            for (i, &(_, r)) in group.iter().enumerate() {
                self.out[r] = self.sub_out[i].map(|j| cs[j].1);
            }
        }
        self.members_r = members_r;
        self.members_c = members_c;
        self.sub = sub;
        &self.out
    }

    /// The Hungarian method on a whole `rows × cols` matrix, into `sub_out` (`rows` entries,
    /// all `None` on entry: the caller's shortcut leaves it so when it does not apply).
    fn solve_dense(&mut self, cost: &[f64], rows: usize, cols: usize) {
        // Finite stand-in for "not allowed", larger than any sum of allowed costs.
        let finite_max = cost
            .iter()
            .filter(|c| c.is_finite())
            .fold(0.0f64, |a, &c| a.max(c.abs()));
        let n = rows.max(cols);
        let big = (finite_max + 1.0) * (n as f64 + 1.0) * 4.0;
        // The square `n × n` matrix the method works on, padded and with `big` for "not
        // allowed", made once so the inner loop reads a plain row.
        self.square.clear();
        for r in 0..n {
            if r < rows {
                let row = &cost[r * cols..(r + 1) * cols];
                self.square
                    .extend(row.iter().map(|&v| if v.is_finite() { v } else { big }));
            }
            self.square.resize((r + 1) * n, big);
        }
        // Potentials u (rows), v (cols); p[c] = row matched to col c (1-based, 0 = none).
        for buf in [&mut self.u, &mut self.v] {
            buf.clear();
            buf.resize(n + 1, 0.0);
        }
        for buf in [&mut self.p, &mut self.way] {
            buf.clear();
            buf.resize(n + 1, 0);
        }
        self.minv.clear();
        self.minv.resize(n + 1, f64::INFINITY);
        self.used.clear();
        self.used.resize(n + 1, false);
        let (u, v, p, way) = (&mut self.u, &mut self.v, &mut self.p, &mut self.way);
        let (minv, used) = (&mut self.minv, &mut self.used);
        for i in 1..=n {
            p[0] = i;
            let mut j0 = 0usize;
            minv.fill(f64::INFINITY);
            used.fill(false);
            loop {
                used[j0] = true;
                let i0 = p[j0];
                let mut delta = f64::INFINITY;
                let mut j1 = 0usize;
                let (row, ui0) = (&self.square[(i0 - 1) * n..i0 * n], u[i0]);
                let columns = row.iter().zip(&v[1..]).zip(&used[1..]);
                for (k, (((&c, &vj), &done), (mv, wj))) in columns
                    .zip(minv[1..].iter_mut().zip(&mut way[1..]))
                    .enumerate()
                {
                    if done {
                        continue;
                    }
                    let cur = c - ui0 - vj;
                    if cur < *mv {
                        *mv = cur;
                        *wj = j0;
                    }
                    if *mv < delta {
                        delta = *mv;
                        j1 = k + 1;
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
        for j in 1..=n {
            let i = p[j];
            if i >= 1 && i <= rows && j <= cols && cost[(i - 1) * cols + (j - 1)].is_finite() {
                self.sub_out[i - 1] = Some(j - 1);
            }
        }
    }
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

    /// Sparse matrices, as tracking makes them (most pairs gated out): they fall apart into
    /// components, each solved on its own; the whole must still be the optimum.
    #[test]
    fn components_solved_apart_give_the_optimum() {
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
            // Two rows with the same cheapest column make the components (and the general
            // method) run rather than the shortcut.
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
        assert!(split > 80, "{split} trials reached the components");
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
