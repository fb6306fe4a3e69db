//! In-place Cholesky factorisation `A = L L^T` of a dense symmetric positive definite
//! matrix and the two triangular solves, for the small normal equations of the solvers
//! (row-major `n x n` slices, no allocation).
//!
//! Only the lower triangle (diagonal included) of the input is read and overwritten by
//! `L`; the strict upper triangle is left as it was. The row dot products use four
//! independent accumulators and are compiled for the CPU level `pulp` dispatches to.
//!
//! ```
//! use facecap_geom::cholesky;
//! let mut a = [4.0, 2.0, 2.0, 3.0];
//! let mut b = [2.0, 1.0];
//! cholesky::solve(&mut a, 2, &mut b).map_err(|pivot| format!("pivot {pivot}"))?;
//! assert!((4.0 * b[0] + 2.0 * b[1] - 2.0).abs() < 1e-12);
//! assert!((2.0 * b[0] + 3.0 * b[1] - 1.0).abs() < 1e-12);
//! # Ok::<(), String>(())
//! ```

/// Factorises the leading `n x n` block of `a` (stride `n`) in place.
///
/// # Errors
/// The index of the first pivot that is not positive and finite (the matrix is not
/// positive definite, or holds NaN/inf); `a` is then partly overwritten.
pub fn factor(a: &mut [f64], n: usize) -> Result<(), usize> {
    pulp::Arch::new().dispatch(Factor { a, n })
}

/// Solves `L L^T x = b` in place for a factor `l` from [`factor`].
pub fn solve_factored(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        b[i] = (b[i] - dot(&l[i * n..i * n + i], &b[..i])) / l[i * n + i];
    }
    // L^T x = y by columns of L^T, i.e. rows of L: once x_i is known, it is taken out of
    // every earlier equation (a contiguous axpy along row i, where the row-by-row form
    // would walk down a column of the row-major factor)
    for i in (0..n).rev() {
        let xi = b[i] / l[i * n + i];
        b[i] = xi;
        for (bk, lik) in b[..i].iter_mut().zip(&l[i * n..i * n + i]) {
            *bk -= lik * xi;
        }
    }
}

/// Solves `A x = b` in place: `a` is overwritten by its factor, `b` by the solution.
///
/// # Errors
/// As [`factor`]; `b` is then unchanged.
pub fn solve(a: &mut [f64], n: usize, b: &mut [f64]) -> Result<(), usize> {
    pulp::Arch::new().dispatch(Solve { a, n, b })
}

struct Factor<'a> {
    a: &'a mut [f64],
    n: usize,
}

impl pulp::WithSimd for Factor<'_> {
    type Output = Result<(), usize>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Result<(), usize> {
        factor_inner(self.a, self.n)
    }
}

struct Solve<'a> {
    a: &'a mut [f64],
    n: usize,
    b: &'a mut [f64],
}

impl pulp::WithSimd for Solve<'_> {
    type Output = Result<(), usize>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Result<(), usize> {
        factor_inner(self.a, self.n)?;
        solve_factored(self.a, self.n, self.b);
        Ok(())
    }
}

#[inline(always)]
fn factor_inner(a: &mut [f64], n: usize) -> Result<(), usize> {
    for j in 0..n {
        let (_, from_j) = a.split_at_mut(j * n);
        let (rowj, below) = from_j.split_at_mut(n);
        let d = rowj[j] - dot(&rowj[..j], &rowj[..j]);
        if !(d > 0.0 && d.is_finite()) {
            return Err(j);
        }
        let d = d.sqrt();
        rowj[j] = d;
        for rowi in below.chunks_exact_mut(n).take(n - j - 1) {
            rowi[j] = (rowi[j] - dot(&rowi[..j], &rowj[..j])) / d;
        }
    }
    Ok(())
}

/// Dot product of the common prefix of `a` and `b`, with four independent accumulators so
/// that the compiler vectorises the reduction (the kernel of the solves here and of the
/// tensor fit's design-matrix products).
///
/// ```
/// assert_eq!(facecap_geom::cholesky::dot(&[1.0, 2.0, 3.0, 4.0, 5.0], &[1.0; 5]), 15.0);
/// ```
#[inline(always)]
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    // Four independent accumulators let the compiler vectorise the reduction.
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for j in 0..4 {
            acc[j] += x[j] * y[j];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_spd_system_and_rejects_an_indefinite_one() {
        // A = M M^T + I for a fixed M: SPD.
        let n = 7;
        let m: Vec<f64> = (0..n * n).map(|k| ((k * 37 % 11) as f64 - 5.0) / 3.0).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| m[i * n + k] * m[j * n + k]).sum::<f64>() + f64::from(u8::from(i == j));
            }
        }
        let x_true: Vec<f64> = (0..n).map(|i| i as f64 - 2.5).collect();
        let mut b: Vec<f64> = (0..n).map(|i| (0..n).map(|j| a[i * n + j] * x_true[j]).sum()).collect();
        let mut f = a.clone();
        assert_eq!(solve(&mut f, n, &mut b), Ok(()));
        for (x, t) in b.iter().zip(&x_true) {
            assert!((x - t).abs() < 1e-9, "{x} vs {t}");
        }
        let mut bad = [1.0, 2.0, 2.0, 1.0];
        assert_eq!(factor(&mut bad, 2), Err(1));
        let mut nan = [f64::NAN];
        assert_eq!(factor(&mut nan, 1), Err(0));
    }

    #[test]
    fn factor_reads_only_the_leading_block() {
        // A longer buffer: only the first n*n entries are the matrix.
        let mut a = vec![4.0, 2.0, 2.0, 3.0, 99.0, 99.0];
        assert_eq!(factor(&mut a, 2), Ok(()));
        assert_eq!(&a[4..], &[99.0, 99.0]);
        assert!((a[0] - 2.0).abs() < 1e-15 && (a[2] - 1.0).abs() < 1e-15 && (a[3] - 2f64.sqrt()).abs() < 1e-15);
    }
}
