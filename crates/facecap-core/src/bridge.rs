//! The one bridge between the two linear-algebra worlds: nalgebra (small fixed-size
//! geometry) and ndarray (large dynamic data: bases, tensors).
//!
//! Layout convention for point sets in ndarray: shape `(n, 3)` (or `(n, 2)`),
//! row-major, one point per row; flattened vectors are `[x0, y0, z0, x1, ...]`.

use nalgebra::{DMatrix, Point2, Point3};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use crate::error::{Error, Result};

/// Points to an `(n, 3)` array.
pub fn points3_to_array(points: &[Point3<f64>]) -> Array2<f64> {
    Array2::from_shape_fn((points.len(), 3), |(i, j)| points[i][j])
}

/// `(n, 3)` array to points.
///
/// # Errors
/// When the array does not have 3 columns.
pub fn array_to_points3(a: ArrayView2<'_, f64>) -> Result<Vec<Point3<f64>>> {
    if a.ncols() != 3 {
        return Err(Error::DimensionMismatch {
            what: "point array columns".into(),
            expected: 3,
            got: a.ncols(),
        });
    }
    Ok(a.rows().into_iter().map(|r| Point3::new(r[0], r[1], r[2])).collect())
}

/// 2D points to an `(n, 2)` array.
pub fn points2_to_array(points: &[Point2<f64>]) -> Array2<f64> {
    Array2::from_shape_fn((points.len(), 2), |(i, j)| points[i][j])
}

/// 3D points flattened to `[x0, y0, z0, x1, ...]`.
pub fn flatten_points3(points: &[Point3<f64>]) -> Array1<f64> {
    points.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
}

/// A flat `[x0, y0, z0, ...]` vector back to points.
///
/// # Errors
/// When the length is not a multiple of 3.
pub fn unflatten_points3(v: ArrayView1<'_, f64>) -> Result<Vec<Point3<f64>>> {
    if v.len() % 3 != 0 {
        return Err(Error::invalid("flat point vector length", v.len(), "a multiple of 3"));
    }
    Ok((0..v.len() / 3)
        .map(|i| Point3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]))
        .collect())
}

/// nalgebra dynamic matrix to ndarray (same shape).
pub fn dmatrix_to_array(m: &DMatrix<f64>) -> Array2<f64> {
    Array2::from_shape_fn((m.nrows(), m.ncols()), |(i, j)| m[(i, j)])
}

/// ndarray matrix to nalgebra dynamic matrix (same shape).
pub fn array_to_dmatrix(a: ArrayView2<'_, f64>) -> DMatrix<f64> {
    DMatrix::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        let pts = vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.0, 5.5, 6.0)];
        let a = points3_to_array(&pts);
        assert_eq!(a.shape(), &[2, 3]);
        assert_eq!(array_to_points3(a.view()).unwrap(), pts);
        let f = flatten_points3(&pts);
        assert_eq!(unflatten_points3(f.view()).unwrap(), pts);
        assert!(unflatten_points3(f.slice(ndarray::s![..4])).is_err());
        let m = DMatrix::from_fn(3, 2, |i, j| (i * 10 + j) as f64);
        assert_eq!(array_to_dmatrix(dmatrix_to_array(&m).view()), m);
        assert!(array_to_points3(Array2::<f64>::zeros((2, 2)).view()).is_err());
    }
}
