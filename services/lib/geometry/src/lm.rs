//! Levenberg–Marquardt for problems made of shared ("global") parameters and many small
//! per-view blocks — camera calibration's structure: intrinsics shared by every view, one
//! pose per view. The normal equations are solved through the Schur complement on the global
//! block, so cost grows linearly with the number of views.
//!
//! Not a thesis equation: the thesis calibrated by measuring. Jacobians are central finite
//! differences (each global parameter re-evaluates every view; each view parameter only its
//! own view).

use nalgebra::{DMatrix, DVector};

/// A least-squares problem with global parameters and per-view blocks.
pub trait BlockProblem {
    fn global_len(&self) -> usize;
    fn view_count(&self) -> usize;
    fn view_len(&self) -> usize;
    /// The residuals of view `view` (always the same length for a view), or `None` if the
    /// parameters are invalid there (a point behind the camera): the step is then rejected.
    fn residuals(
        &self,
        global: &[f64],
        view: usize,
        view_params: &[f64],
        out: &mut Vec<f64>,
    ) -> Option<()>;
    /// Finite-difference step for global parameter `k` at value `x`.
    fn global_step(&self, _k: usize, x: f64) -> f64 {
        1e-6 * x.abs().max(1e-3)
    }
}

/// What the solver did.
#[derive(Debug, Clone, PartialEq)]
pub struct LmReport {
    pub iterations: usize,
    pub initial_cost: f64,
    /// Sum of squared residuals at the end.
    pub final_cost: f64,
    pub residual_count: usize,
    /// Inverse of the Gauss–Newton matrix's global block after eliminating the views
    /// (multiply by the residual variance for the covariance of the global parameters).
    pub global_inverse: Option<DMatrix<f64>>,
}

fn total_cost<P: BlockProblem>(
    p: &P,
    g: &[f64],
    views: &[Vec<f64>],
    buf: &mut Vec<f64>,
) -> Option<(f64, usize)> {
    let (mut c, mut n) = (0.0, 0usize);
    for (i, v) in views.iter().enumerate() {
        buf.clear();
        p.residuals(g, i, v, buf)?;
        c += buf.iter().map(|r| r * r).sum::<f64>();
        n += buf.len();
    }
    Some((c, n))
}

struct Linearised {
    hgg: DMatrix<f64>,
    hgv: Vec<DMatrix<f64>>,
    hvv: Vec<DMatrix<f64>>,
    bg: DVector<f64>,
    bv: Vec<DVector<f64>>,
}

fn linearise<P: BlockProblem>(p: &P, g: &[f64], views: &[Vec<f64>]) -> Option<Linearised> {
    let (ng, nv) = (p.global_len(), p.view_len());
    let mut hgg = DMatrix::zeros(ng, ng);
    let mut bg = DVector::zeros(ng);
    let (mut hgv, mut hvv, mut bv) = (Vec::new(), Vec::new(), Vec::new());
    let mut r0 = Vec::new();
    let (mut rp, mut rm) = (Vec::new(), Vec::new());
    let mut gg = g.to_vec();
    for (i, v) in views.iter().enumerate() {
        r0.clear();
        p.residuals(g, i, v, &mut r0)?;
        let m = r0.len();
        let mut jg = DMatrix::zeros(m, ng);
        for k in 0..ng {
            let h = p.global_step(k, g[k]);
            gg[k] = g[k] + h;
            rp.clear();
            p.residuals(&gg, i, v, &mut rp)?;
            gg[k] = g[k] - h;
            rm.clear();
            p.residuals(&gg, i, v, &mut rm)?;
            gg[k] = g[k];
            for r in 0..m {
                jg[(r, k)] = (rp[r] - rm[r]) / (2.0 * h);
            }
        }
        let mut jv = DMatrix::zeros(m, nv);
        let mut vv = v.clone();
        for k in 0..nv {
            let h = 1e-6 * v[k].abs().max(1e-3);
            vv[k] = v[k] + h;
            rp.clear();
            p.residuals(g, i, &vv, &mut rp)?;
            vv[k] = v[k] - h;
            rm.clear();
            p.residuals(g, i, &vv, &mut rm)?;
            vv[k] = v[k];
            for r in 0..m {
                jv[(r, k)] = (rp[r] - rm[r]) / (2.0 * h);
            }
        }
        let r = DVector::from_column_slice(&r0);
        hgg += jg.transpose() * &jg;
        bg += jg.transpose() * &r;
        hgv.push(jg.transpose() * &jv);
        hvv.push(jv.transpose() * &jv);
        bv.push(jv.transpose() * &r);
    }
    Some(Linearised {
        hgg,
        hgv,
        hvv,
        bg,
        bv,
    })
}

/// A damped step: global step, view steps, inverse of the reduced global matrix.
type Step = (DVector<f64>, Vec<DVector<f64>>, DMatrix<f64>);

/// Solves the damped normal equations by the Schur complement.
fn solve_damped(l: &Linearised, lambda: f64) -> Option<Step> {
    let damp = |m: &DMatrix<f64>| {
        let mut d = m.clone();
        for k in 0..d.nrows() {
            d[(k, k)] += lambda * m[(k, k)].max(1e-12);
        }
        d
    };
    let mut s = damp(&l.hgg);
    let mut rhs = l.bg.clone();
    let mut inv_vv = Vec::with_capacity(l.hvv.len());
    for i in 0..l.hvv.len() {
        let w = damp(&l.hvv[i]).try_inverse()?;
        let gw = &l.hgv[i] * &w;
        s -= &gw * l.hgv[i].transpose();
        rhs -= &gw * &l.bv[i];
        inv_vv.push(w);
    }
    let s_inv = s.clone().try_inverse()?;
    let dg = &s_inv * &rhs;
    let dv = (0..l.hvv.len())
        .map(|i| &inv_vv[i] * (&l.bv[i] - l.hgv[i].transpose() * &dg))
        .collect();
    Some((dg, dv, s_inv))
}

/// Minimises the sum of squared residuals over `global` and `views` in place.
pub fn solve<P: BlockProblem>(
    p: &P,
    global: &mut [f64],
    views: &mut [Vec<f64>],
    max_iterations: usize,
) -> LmReport {
    let mut buf = Vec::new();
    let Some((mut cost, residual_count)) = total_cost(p, global, views, &mut buf) else {
        return LmReport {
            iterations: 0,
            initial_cost: f64::INFINITY,
            final_cost: f64::INFINITY,
            residual_count: 0,
            global_inverse: None,
        };
    };
    let initial_cost = cost;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for _ in 0..max_iterations {
        iterations += 1;
        let Some(lin) = linearise(p, global, views) else {
            break;
        };
        let mut accepted = false;
        let mut converged = false;
        for _ in 0..15 {
            let Some((dg, dv, _)) = solve_damped(&lin, lambda) else {
                lambda *= 10.0;
                continue;
            };
            let g_new: Vec<f64> = global.iter().zip(dg.iter()).map(|(x, d)| x - d).collect();
            let v_new: Vec<Vec<f64>> = views
                .iter()
                .zip(&dv)
                .map(|(v, d)| v.iter().zip(d.iter()).map(|(x, s)| x - s).collect())
                .collect();
            match total_cost(p, &g_new, &v_new, &mut buf) {
                Some((c, _)) if c < cost => {
                    let rel = (cost - c) / cost.max(1e-300);
                    global.copy_from_slice(&g_new);
                    for (v, n) in views.iter_mut().zip(v_new) {
                        *v = n;
                    }
                    cost = c;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = true;
                    converged = rel < 1e-12;
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        if !accepted || converged {
            break;
        }
    }
    let global_inverse = linearise(p, global, views)
        .and_then(|l| solve_damped(&l, 0.0))
        .map(|(_, _, s)| s);
    LmReport {
        iterations,
        initial_cost,
        final_cost: cost,
        residual_count,
        global_inverse,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fit y = a·exp(b·x) + c_i per group: global (a, b), per view (c_i) — a small block
    /// problem with a known answer.
    struct Curves {
        data: Vec<Vec<(f64, f64)>>,
    }

    impl BlockProblem for Curves {
        fn global_len(&self) -> usize {
            2
        }
        fn view_count(&self) -> usize {
            self.data.len()
        }
        fn view_len(&self) -> usize {
            1
        }
        fn residuals(&self, g: &[f64], view: usize, v: &[f64], out: &mut Vec<f64>) -> Option<()> {
            for &(x, y) in &self.data[view] {
                out.push(g[0] * (g[1] * x).exp() + v[0] - y);
            }
            Some(())
        }
    }

    #[test]
    fn recovers_global_and_per_view_parameters() {
        let (a, b) = (2.5, -0.7);
        let offsets = [0.3, -1.2, 4.0, 0.0];
        let data = offsets
            .iter()
            .map(|c| {
                (0..20)
                    .map(|k| {
                        let x = k as f64 * 0.2;
                        (x, a * (b * x).exp() + c)
                    })
                    .collect()
            })
            .collect();
        let p = Curves { data };
        let mut g = vec![1.0, -0.1];
        let mut v: Vec<Vec<f64>> = vec![vec![0.0]; 4];
        let rep = solve(&p, &mut g, &mut v, 100);
        assert!(
            (g[0] - a).abs() < 1e-6 && (g[1] - b).abs() < 1e-6,
            "{g:?} after {rep:?}"
        );
        for (vi, c) in v.iter().zip(offsets) {
            assert!((vi[0] - c).abs() < 1e-6);
        }
        assert!(rep.final_cost < 1e-12 && rep.final_cost < rep.initial_cost);
        assert_eq!(rep.residual_count, 80);
        assert!(rep.global_inverse.is_some());
    }
}
