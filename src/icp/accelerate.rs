//! Anderson acceleration of the ICP loop (Walker & Ni 2011; for ICP, Pavlov
//! et al. 2018, "AA-ICP").
//!
//! Point-to-surface steps on noisy DSMs are short: the fit takes the noise
//! slopes of the reference for information, so each step covers only a part
//! of the way (errors in variables), and the loop creeps to its fixed point at
//! a steady rate, 0.8-0.9 per iteration on 0.5 m city tiles with 0.3 m noise
//! (20-30 iterations per level). The fixed point is the answer; how the loop
//! walks there is not. Anderson acceleration takes the next pose as the
//! combination of the last few plain steps' ends whose residual steps cancel
//! best, which jumps along such a steady creep.
//!
//! Poses are charted as 6-vectors about the loop's start (the translation and
//! the rotation vector of `t start^-1`, the rotation scaled by the overlap's
//! lever arm so that both are metres at its edge, the convergence rule's
//! measure). Safeguards keep it a plain loop where it cannot help: the
//! history is dropped when a step grows (an extrapolation overshot), a jump
//! longer than [`MAX_JUMP`] plain steps is not taken, and steps already at
//! the noise floor (below `floor_m`) are taken plain, so the stopping rule
//! sees the loop's own jitter. The loop still stops on a plain step, so the
//! answer is the same fixed point.

use std::collections::VecDeque;

use nalgebra::{DMatrix, DVector, Isometry3, Translation3, UnitQuaternion, Vector3, Vector6};

/// Past steps combined (the depth m of Anderson acceleration).
pub const DEPTH: usize = 3;
/// The longest jump beyond a plain step's end, in plain steps.
pub const MAX_JUMP: f64 = 10.0;

/// The history of one loop (one point set, one start).
pub(super) struct Anderson {
    origin: Isometry3<f64>,
    lever_m: f64,
    floor_m: f64,
    /// Charted poses where each step was fitted, and the steps' ends.
    xs: VecDeque<Vector6<f64>>,
    gs: VecDeque<Vector6<f64>>,
}

impl Anderson {
    /// A loop starting at `origin`, its rotations weighed at `lever_m` and its
    /// steps below `floor_m` taken plain.
    pub fn new(origin: &Isometry3<f64>, lever_m: f64, floor_m: f64) -> Self {
        Anderson {
            origin: *origin,
            lever_m: lever_m.max(1e-9),
            floor_m,
            xs: VecDeque::with_capacity(DEPTH + 1),
            gs: VecDeque::with_capacity(DEPTH + 1),
        }
    }

    fn chart(&self, t: &Isometry3<f64>) -> Vector6<f64> {
        let d = t * self.origin.inverse();
        let (v, r) = (
            d.translation.vector,
            d.rotation.scaled_axis() * self.lever_m,
        );
        Vector6::new(v.x, v.y, v.z, r.x, r.y, r.z)
    }

    fn unchart(&self, c: &Vector6<f64>) -> Isometry3<f64> {
        let rotation = Vector3::new(c[3], c[4], c[5]) / self.lever_m;
        Isometry3::from_parts(
            Translation3::new(c[0], c[1], c[2]),
            UnitQuaternion::from_scaled_axis(rotation),
        ) * self.origin
    }

    /// The pose to match next after a plain step from `x` ended at `g`:
    /// `g` itself, or the accelerated pose.
    pub fn next(&mut self, x: &Isometry3<f64>, g: &Isometry3<f64>) -> Isometry3<f64> {
        let (xc, gc) = (self.chart(x), self.chart(g));
        let f = gc - xc;
        let grew = match (self.xs.back(), self.gs.back()) {
            (Some(px), Some(pg)) => f.norm() > (pg - px).norm(),
            _ => false,
        };
        if grew || !f.iter().all(|v| v.is_finite()) {
            self.xs.clear();
            self.gs.clear();
        }
        if self.xs.len() == DEPTH + 1 {
            self.xs.pop_front();
            self.gs.pop_front();
        }
        self.xs.push_back(xc);
        self.gs.push_back(gc);
        if f.norm() < self.floor_m {
            return *g;
        }
        match combine(&self.xs, &self.gs) {
            Some(next) if (next - gc).norm() <= MAX_JUMP * f.norm() => self.unchart(&next),
            _ => *g,
        }
    }
}

/// Anderson's type-II combination of the history: with residuals f_i = g_i -
/// x_i, the gamma minimising |f_k - dF gamma| (dF: differences of consecutive
/// residuals) gives g_k - dG gamma. None with fewer than two entries or an
/// unusable least-squares problem.
fn combine(xs: &VecDeque<Vector6<f64>>, gs: &VecDeque<Vector6<f64>>) -> Option<Vector6<f64>> {
    let n = xs.len();
    if n < 2 {
        return None;
    }
    let fs: Vec<Vector6<f64>> = xs.iter().zip(gs).map(|(x, g)| g - x).collect();
    let k = n - 1;
    let mut df = DMatrix::<f64>::zeros(6, k);
    let mut dg = DMatrix::<f64>::zeros(6, k);
    for j in 0..k {
        df.set_column(j, &(fs[j + 1] - fs[j]));
        dg.set_column(j, &(gs[j + 1] - gs[j]));
    }
    // normal equations with a tiny ridge: k <= DEPTH columns, and collinear
    // differences (a steady creep along one direction) stay solvable
    let mut normal = df.transpose() * &df;
    let ridge = 1e-10 * normal.trace().max(f64::MIN_POSITIVE);
    for j in 0..k {
        normal[(j, j)] += ridge;
    }
    let rhs = df.transpose() * DVector::from_column_slice(fs[k].as_slice());
    let gamma = normal.cholesky()?.solve(&rhs);
    let step = &dg * gamma;
    let next = gs[k] - Vector6::from_column_slice(step.as_slice());
    next.iter().all(|v| v.is_finite()).then_some(next)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(c: &Vector6<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(c[0], c[1], c[2]),
            UnitQuaternion::from_scaled_axis(Vector3::new(c[3], c[4], c[5]) / 100.0),
        )
    }

    /// A plain loop creeping to its fixed point at 0.88 per step along one
    /// direction and 0.5 along the others: about 60 steps to a tenth of a
    /// millimetre plain, a handful accelerated, at the same point.
    #[test]
    fn a_steady_creep_is_jumped() {
        let fixed = Vector6::new(0.4, -1.2, 2.6, 0.05, -0.02, 0.3);
        let rates = Vector6::new(0.88, 0.5, 0.5, 0.5, 0.5, 0.88);
        let step = |x: &Vector6<f64>| fixed + (x - fixed).component_mul(&rates);
        let origin = Isometry3::identity();
        let run = |accelerate: bool| {
            let mut aa = Anderson::new(&origin, 100.0, 1e-9);
            let mut x = Vector6::zeros();
            for k in 1..500 {
                let g = step(&x);
                if (g - x).norm() < 1e-4 {
                    return (k, g);
                }
                x = if accelerate {
                    let next = aa.next(&pose(&x), &pose(&g));
                    aa.chart(&next)
                } else {
                    g
                };
            }
            (500, x)
        };
        let (plain, at_plain) = run(false);
        let (fast, at_fast) = run(true);
        assert!(plain > 50, "plain {plain}");
        assert!(fast <= 8, "accelerated {fast}");
        assert!((at_plain - fixed).norm() < 1e-3 && (at_fast - fixed).norm() < 1e-5);
    }

    /// Steps at the noise floor are taken plain; an overshoot (a step that
    /// grows) drops the history; a jump beyond MAX_JUMP steps is not taken.
    #[test]
    fn the_safeguards_keep_a_plain_loop() {
        let origin = Isometry3::identity();
        let c = |x: f64| pose(&Vector6::new(x, 0.0, 0.0, 0.0, 0.0, 0.0));
        let mut aa = Anderson::new(&origin, 100.0, 1e-3);
        aa.next(&c(0.0), &c(5e-4));
        assert_eq!(aa.next(&c(5e-4), &c(9e-4)), c(9e-4), "below the floor");
        let mut aa = Anderson::new(&origin, 100.0, 0.0);
        aa.next(&c(0.0), &c(1.0));
        let jumped = aa.next(&c(1.0), &c(1.9));
        assert!((jumped.translation.x - 10.0).abs() < 1e-6, "{jumped:?}");
        // the step after a jump grows: plain again, history dropped
        assert_eq!(aa.next(&c(10.0), &c(8.0)), c(8.0));
        assert_eq!(aa.xs.len(), 1);
        // a near-stall (0.999 per step) would jump a thousand steps: refused
        let mut aa = Anderson::new(&origin, 100.0, 0.0);
        aa.next(&c(0.0), &c(1.0));
        assert_eq!(aa.next(&c(1.0), &c(1.999)), c(1.999));
    }
}
