//! MediaPipe's video-mode landmark smoothing: a one-euro filter per coordinate
//! (Casiez, Roussel & Vogel 2012, "1 Euro Filter"), as `LandmarksSmoothingCalculator`
//! with FaceLandmarker's settings (`min_cutoff` 0.05, `beta` 80, `derivate_cutoff` 1).
//!
//! Per coordinate `x` at time `t` (seconds), with `f = 1 / (t - t_prev)` (30 Hz before
//! two samples exist) and `alpha(fc) = 1 / (1 + f / (2 pi fc))`:
//!
//! ```text
//! dx   = (x - x_prev_raw) * s * f           s = 1 / object scale (mean of the landmarks'
//!                                            bounding-box width and height, pixels)
//! edx  = lowpass(dx, alpha(derivate_cutoff))
//! x'   = lowpass(x, alpha(min_cutoff + beta * |edx|))
//! ```
//!
//! A sample whose timestamp is not after the previous one passes through unfiltered
//! (MediaPipe does the same); a lost face resets the filters.

use crate::tracker::FaceMesh;
use crate::{Error, Result};

/// One-euro settings (FaceLandmarker's values by default).
///
/// | name | default | meaning | range |
/// |---|---|---|---|
/// | `min_cutoff` | 0.05 | cutoff frequency (Hz) of a still landmark | > 0 |
/// | `beta` | 80 | cutoff increase per unit of scaled speed | >= 0 |
/// | `derivate_cutoff` | 1.0 | cutoff (Hz) of the speed estimate | > 0 |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmoothingParams {
    /// Minimum cutoff frequency in Hz.
    pub min_cutoff: f64,
    /// Speed coefficient.
    pub beta: f64,
    /// Cutoff frequency of the derivative in Hz.
    pub derivate_cutoff: f64,
}

impl Default for SmoothingParams {
    fn default() -> Self {
        SmoothingParams {
            min_cutoff: 0.05,
            beta: 80.0,
            derivate_cutoff: 1.0,
        }
    }
}

/// Frequency assumed before two timestamps are known (MediaPipe's default).
const DEFAULT_FREQUENCY: f64 = 30.0;
/// Below this object scale smoothing is skipped (MediaPipe's `min_allowed_object_scale`).
const MIN_OBJECT_SCALE: f32 = 1e-6;

#[derive(Debug, Clone, Copy, Default)]
struct LowPass {
    init: bool,
    raw: f64,
    stored: f64,
}

impl LowPass {
    fn apply(&mut self, v: f64, alpha: f64) -> f64 {
        let r = if self.init {
            alpha * v + (1.0 - alpha) * self.stored
        } else {
            self.init = true;
            v
        };
        self.raw = v;
        self.stored = r;
        r
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct Euro {
    x: LowPass,
    dx: LowPass,
}

/// Filter state of one face over a video (the `State` of smoothing).
#[derive(Debug, Clone)]
pub struct LandmarkSmoother {
    params: SmoothingParams,
    filters: Vec<Euro>,
    last_ns: i64,
    frequency: f64,
}

fn alpha(frequency: f64, cutoff: f64) -> f64 {
    let te = 1.0 / frequency;
    let tau = 1.0 / (2.0 * std::f64::consts::PI * cutoff);
    1.0 / (1.0 + tau / te)
}

impl LandmarkSmoother {
    /// A fresh smoother.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-positive or non-finite cutoff or a negative beta.
    pub fn new(params: SmoothingParams) -> Result<Self> {
        let pos = |name, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Error::InvalidParameter {
                    name,
                    value: v.to_string(),
                    expected: "a finite number > 0".into(),
                })
            }
        };
        pos("min_cutoff", params.min_cutoff)?;
        pos("derivate_cutoff", params.derivate_cutoff)?;
        if !(params.beta.is_finite() && params.beta >= 0.0) {
            return Err(Error::InvalidParameter {
                name: "beta",
                value: params.beta.to_string(),
                expected: "a finite number >= 0".into(),
            });
        }
        Ok(LandmarkSmoother {
            params,
            filters: Vec::new(),
            last_ns: 0,
            frequency: DEFAULT_FREQUENCY,
        })
    }

    /// Forgets the history (call when the face is lost).
    pub fn reset(&mut self) {
        self.filters.clear();
        self.last_ns = 0;
        self.frequency = DEFAULT_FREQUENCY;
    }

    /// Smooths `mesh.points` in place; `timestamp_s` is the frame time in seconds.
    /// Allocates only on the first call after a reset.
    pub fn apply(&mut self, timestamp_s: f64, mesh: &mut FaceMesh) {
        // MediaPipe works on integer nanoseconds (absl::Duration).
        let ns = (timestamp_s * 1e9).round() as i64;
        if self.filters.len() != mesh.points.len() * 3 {
            self.filters.clear();
            self.filters.resize(mesh.points.len() * 3, Euro::default());
            self.last_ns = 0;
            self.frequency = DEFAULT_FREQUENCY;
        }
        if self.last_ns >= ns {
            return;
        }
        if self.last_ns != 0 && ns != 0 {
            self.frequency = 1.0 / ((ns - self.last_ns) as f64 * 1e-9);
        }
        self.last_ns = ns;
        let (mut x0, mut y0, mut x1, mut y1) = (f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
        for p in &mesh.points {
            x0 = x0.min(p[0]);
            x1 = x1.max(p[0]);
            y0 = y0.min(p[1]);
            y1 = y1.max(p[1]);
        }
        let scale = ((x1 - x0) + (y1 - y0)) / 2.0;
        if scale.is_nan() || scale < MIN_OBJECT_SCALE {
            return;
        }
        let value_scale = 1.0 / scale as f64;
        let f = self.frequency;
        let p = self.params;
        let a_d = alpha(f, p.derivate_cutoff);
        for (pt, fl) in mesh.points.iter_mut().zip(self.filters.chunks_exact_mut(3)) {
            for (v, e) in pt.iter_mut().zip(fl.iter_mut()) {
                let x = *v as f64;
                let dx = if e.x.init { (x - e.x.raw) * value_scale * f } else { 0.0 };
                let edx = e.dx.apply(dx, a_d);
                let cutoff = p.min_cutoff + p.beta * edx.abs();
                *v = e.x.apply(x, alpha(f, cutoff)) as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mesh(v: f32) -> FaceMesh {
        FaceMesh {
            points: vec![[v, 0.0, 0.0], [v + 10.0, 10.0, 0.0]],
            ..Default::default()
        }
    }

    #[test]
    fn still_points_stay_and_a_step_is_damped() {
        let mut s = LandmarkSmoother::new(SmoothingParams::default()).unwrap_or_else(|_| unreachable!());
        for i in 0..5 {
            let mut m = mesh(100.0);
            s.apply(i as f64 / 30.0, &mut m);
            assert_eq!(m.points[0][0], 100.0);
        }
        let mut m = mesh(101.0);
        s.apply(5.0 / 30.0, &mut m);
        let x = m.points[0][0];
        assert!(x > 100.0 && x < 101.0, "step filtered to {x}");
        // Repeated timestamps pass through unfiltered.
        let mut m = mesh(150.0);
        s.apply(5.0 / 30.0, &mut m);
        assert_eq!(m.points[0][0], 150.0);
    }

    #[test]
    fn bad_params_are_rejected() {
        let p = SmoothingParams {
            min_cutoff: 0.0,
            ..Default::default()
        };
        assert!(matches!(
            LandmarkSmoother::new(p),
            Err(Error::InvalidParameter { name: "min_cutoff", .. })
        ));
    }
}
