//! Slow, obvious reference implementation of pyramidal LK in `f64`, used to
//! test the fixed-point kernel. Direct formulas, no padding tricks, no
//! fixed-point: a 5x5 Gaussian for `pyrDown` with explicit reflect-101 indexing,
//! 3x3 Scharr kernels, bilinear interpolation in `f64`, and Bouguet's iteration
//! with the same stopping rules as [`super::PyramidLk`]. Not for production use.

use image::GrayImage;
use nalgebra::{Matrix2, Point2, Vector2};

use super::{LkParams, TrackStatus};

/// A grey image in `f64` (row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct RefImage {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Values, `data[y * width + x]`.
    pub data: Vec<f64>,
}

impl RefImage {
    /// From an 8-bit image.
    pub fn from_gray(img: &GrayImage) -> Self {
        RefImage {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.as_raw().iter().map(|&v| v as f64).collect(),
        }
    }

    /// Value with reflect-101 indexing outside the image.
    pub fn at_reflect(&self, x: i64, y: i64) -> f64 {
        self.data[reflect101(y, self.height) * self.width + reflect101(x, self.width)]
    }

    /// Value, zero outside the image.
    pub fn at_zero(&self, x: i64, y: i64) -> f64 {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            0.0
        } else {
            self.data[y as usize * self.width + x as usize]
        }
    }
}

/// OpenCV `BORDER_REFLECT_101` index mapping (`gfedcb|abcdefgh|gfedcba`).
pub fn reflect101(i: i64, n: usize) -> usize {
    let n = n as i64;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    while i < 0 || i >= n {
        if i < 0 {
            i = -i;
        }
        if i >= n {
            i = 2 * (n - 1) - i;
        }
    }
    i as usize
}

/// `pyrDown`: 5x5 binomial kernel `[1 4 6 4 1]ᵀ[1 4 6 4 1] / 256`, reflect-101,
/// rounded half up to an integer, size `((w+1)/2, (h+1)/2)`.
pub fn pyr_down(img: &RefImage) -> RefImage {
    const K: [f64; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];
    let (w, h) = (img.width.div_ceil(2), img.height.div_ceil(2));
    let mut data = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, kj) in K.iter().enumerate() {
                for (i, ki) in K.iter().enumerate() {
                    s += kj * ki * img.at_reflect(2 * x as i64 + i as i64 - 2, 2 * y as i64 + j as i64 - 2);
                }
            }
            data[y * w + x] = (s / 256.0 + 0.5).floor();
        }
    }
    RefImage {
        width: w,
        height: h,
        data,
    }
}

/// Scharr derivatives `(Ix, Iy)` with reflect-101 borders, in OpenCV's scale
/// (32x the central-difference gradient).
#[allow(clippy::needless_range_loop)] // the 3x3 kernel indices read clearest as indices
pub fn scharr(img: &RefImage) -> (RefImage, RefImage) {
    const KX: [[f64; 3]; 3] = [[-3.0, 0.0, 3.0], [-10.0, 0.0, 10.0], [-3.0, 0.0, 3.0]];
    let mut ix = vec![0.0; img.width * img.height];
    let mut iy = ix.clone();
    for y in 0..img.height {
        for x in 0..img.width {
            let (mut gx, mut gy) = (0.0, 0.0);
            for j in 0..3 {
                for i in 0..3 {
                    let v = img.at_reflect(x as i64 + i as i64 - 1, y as i64 + j as i64 - 1);
                    gx += KX[j][i] * v;
                    gy += KX[i][j] * v;
                }
            }
            ix[y * img.width + x] = gx;
            iy[y * img.width + x] = gy;
        }
    }
    let mk = |data| RefImage {
        width: img.width,
        height: img.height,
        data,
    };
    (mk(ix), mk(iy))
}

/// Pyramid levels as built for LK (stops when the next level would be no larger than the window).
pub fn pyramid(img: &GrayImage, window: usize, max_level: usize) -> Vec<RefImage> {
    let mut out = vec![RefImage::from_gray(img)];
    for _ in 0..max_level {
        let last = &out[out.len() - 1];
        if last.width.div_ceil(2) <= window || last.height.div_ceil(2) <= window {
            break;
        }
        let next = pyr_down(last);
        out.push(next);
    }
    out
}

fn bilinear(f: impl Fn(i64, i64) -> f64, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (a, b) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    (1.0 - a) * (1.0 - b) * f(x0, y0)
        + a * (1.0 - b) * f(x0 + 1, y0)
        + (1.0 - a) * b * f(x0, y0 + 1)
        + a * b * f(x0 + 1, y0 + 1)
}

/// Reference pyramidal LK for `pts` from `prev` to `next` (forward only).
pub fn track(
    prev: &GrayImage,
    next: &GrayImage,
    params: &LkParams,
    pts: &[Point2<f64>],
) -> Vec<(Point2<f64>, TrackStatus)> {
    let pi = pyramid(prev, params.window, params.max_level);
    let pj = pyramid(next, params.window, params.max_level);
    let grads: Vec<(RefImage, RefImage)> = pi.iter().map(scharr).collect();
    let levels = pi.len().min(pj.len());
    let win = params.window as i64;
    let half = (params.window as f64 - 1.0) / 2.0;
    let area = (params.window * params.window) as f64;
    let inside = |c: f64, n: usize| {
        let i = c.floor() as i64;
        i >= -win && i < n as i64
    };
    pts.iter()
        .map(|&p| {
            let mut guess = Vector2::zeros();
            let mut status = TrackStatus::Tracked;
            for level in (0..levels).rev() {
                let scale = 0.5f64.powi(level as i32);
                let u = p.coords * scale;
                guess = if level == levels - 1 { u } else { guess * 2.0 };
                let (img_i, img_j) = (&pi[level], &pj[level]);
                let (gx, gy) = &grads[level];
                let fail = |s: TrackStatus, st: &mut TrackStatus| {
                    if level == 0 {
                        *st = s;
                    }
                };
                if !inside(u.x - half, img_i.width) || !inside(u.y - half, img_i.height) {
                    fail(TrackStatus::LostOutOfImage, &mut status);
                    continue;
                }
                // Window samples of I and its gradient (true gradient = Scharr / 32).
                let offs: Vec<(f64, f64)> = (0..win)
                    .flat_map(|j| (0..win).map(move |i| (i as f64 - half, j as f64 - half)))
                    .collect();
                let mut g = Matrix2::zeros();
                let samples: Vec<(f64, f64, f64)> = offs
                    .iter()
                    .map(|&(dx, dy)| {
                        let (x, y) = (u.x + dx, u.y + dy);
                        let iv = bilinear(|a, b| img_i.at_reflect(a, b), x, y);
                        let ix = bilinear(|a, b| gx.at_zero(a, b), x, y) / 32.0;
                        let iy = bilinear(|a, b| gy.at_zero(a, b), x, y) / 32.0;
                        g += Matrix2::new(ix * ix, ix * iy, ix * iy, iy * iy);
                        (iv, ix, iy)
                    })
                    .collect();
                // OpenCV's gate: λ_min(Σ (32 g)(32 g)ᵀ / 2^20) / area = λ_min(G) / 1024 / area.
                let tr = g[(0, 0)] + g[(1, 1)];
                let disc = ((g[(0, 0)] - g[(1, 1)]).powi(2) + 4.0 * g[(0, 1)].powi(2)).sqrt();
                let min_eig = (tr - disc) / 2.0 / 1024.0 / area;
                let Some(g_inv) = g.try_inverse() else {
                    fail(TrackStatus::LostLowTexture, &mut status);
                    continue;
                };
                if min_eig < params.min_eig_threshold {
                    fail(TrackStatus::LostLowTexture, &mut status);
                    continue;
                }
                let mut prev_delta: Vector2<f64> = Vector2::zeros();
                for it in 0..params.max_iterations {
                    if !inside(guess.x - half, img_j.width) || !inside(guess.y - half, img_j.height) {
                        fail(TrackStatus::LostOutOfImage, &mut status);
                        break;
                    }
                    let mut b = Vector2::zeros();
                    for (&(dx, dy), &(iv, ix, iy)) in offs.iter().zip(samples.iter()) {
                        let jv = bilinear(|a, c| img_j.at_reflect(a, c), guess.x + dx, guess.y + dy);
                        b += Vector2::new(ix, iy) * (jv - iv);
                    }
                    let delta = -(g_inv * b);
                    guess += delta;
                    if delta.norm_squared() <= params.epsilon * params.epsilon {
                        break;
                    }
                    if it > 0 && (delta.x + prev_delta.x).abs() < 0.01 && (delta.y + prev_delta.y).abs() < 0.01 {
                        guess -= delta * 0.5;
                        break;
                    }
                    prev_delta = delta;
                }
            }
            (Point2::from(guess), status)
        })
        .collect()
}
