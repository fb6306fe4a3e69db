//! The One Euro filter (Casiez, Roussel & Vogel, "1€ Filter: A Simple Speed-based
//! Low-pass Filter for Noisy Input in Interactive Systems", CHI 2012).
//!
//! An exponential low-pass filter whose cutoff frequency rises with the signal's
//! speed: slow motion is smoothed strongly (less jitter), fast motion lightly
//! (less lag). For a sample `x_k` at time step `Δt`:
//!
//! ```text
//! α(f)   = 1 / (1 + τ/Δt),  τ = 1 / (2π f)
//! ẋ_k    = (x_k - x̂_{k-1}) / Δt
//! ẋ̂_k    = ẋ̂_{k-1} + α(d_cutoff) (ẋ_k - ẋ̂_{k-1})
//! f_c    = min_cutoff + beta · |ẋ̂_k|
//! x̂_k    = x̂_{k-1} + α(f_c) (x_k - x̂_{k-1})
//! ```
//!
//! | name | default | meaning | range |
//! |---|---|---|---|
//! | `min_cutoff` | 1.0 Hz | cutoff at rest: lower = less jitter, more lag when slow | > 0, finite |
//! | `beta` | 0.05 s/px... (1/px) | how fast the cutoff grows with speed (px/s) | >= 0, finite |
//! | `d_cutoff` | 1.0 Hz | cutoff of the speed estimate | > 0, finite |
//!
//! Units: coordinates in pixels, time in seconds, so `beta` is in 1/px
//! (cutoff Hz per px/s of speed).

use crate::error::{Error, Result};

/// Parameters of the One Euro filter (see the module table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneEuroParams {
    /// Cutoff frequency at rest (Hz).
    pub min_cutoff: f64,
    /// Speed coefficient (Hz per px/s).
    pub beta: f64,
    /// Cutoff of the derivative filter (Hz).
    pub d_cutoff: f64,
}

impl Default for OneEuroParams {
    fn default() -> Self {
        OneEuroParams {
            min_cutoff: 1.0,
            beta: 0.05,
            d_cutoff: 1.0,
        }
    }
}

impl OneEuroParams {
    /// Checks ranges, naming the offending parameter.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`].
    pub fn validate(&self) -> Result<()> {
        let pos = |name: &'static str, v: f64| {
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
        pos("one_euro.min_cutoff", self.min_cutoff)?;
        pos("one_euro.d_cutoff", self.d_cutoff)?;
        if !(self.beta.is_finite() && self.beta >= 0.0) {
            return Err(Error::InvalidParameter {
                name: "one_euro.beta",
                value: self.beta.to_string(),
                expected: "a finite number >= 0".into(),
            });
        }
        Ok(())
    }
}

/// State of one scalar One Euro filter.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OneEuroState {
    x_hat: f64,
    dx_hat: f64,
    initialised: bool,
}

fn alpha(cutoff: f64, dt: f64) -> f64 {
    let tau = 1.0 / (2.0 * std::f64::consts::PI * cutoff);
    1.0 / (1.0 + tau / dt)
}

impl OneEuroState {
    /// Forgets the history (the next sample passes through unchanged).
    pub fn reset(&mut self) {
        self.initialised = false;
    }

    /// Filters sample `x` taken `dt` seconds after the previous one (`dt > 0`;
    /// a non-positive or non-finite `dt` passes `x` through and restarts).
    pub fn filter(&mut self, p: &OneEuroParams, x: f64, dt: f64) -> f64 {
        let dt_ok = dt.is_finite() && dt > 0.0;
        if !self.initialised || !dt_ok {
            *self = OneEuroState {
                x_hat: x,
                dx_hat: 0.0,
                initialised: true,
            };
            return x;
        }
        let dx = (x - self.x_hat) / dt;
        self.dx_hat += alpha(p.d_cutoff, dt) * (dx - self.dx_hat);
        let cutoff = p.min_cutoff + p.beta * self.dx_hat.abs();
        self.x_hat += alpha(cutoff, dt) * (x - self.x_hat);
        self.x_hat
    }
}
