use nalgebra::{Complex, DMatrix};

/// Evaluates a polynomial (descending powers) at a complex point by Horner's rule.
pub fn poly_eval(coefficients: &[f64], s: Complex<f64>) -> Complex<f64> {
    coefficients.iter().fold(Complex::new(0.0, 0.0), |acc, &c| acc * s + c)
}

/// Product of two polynomials.
pub fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, &ai) in a.iter().enumerate() {
        for (j, &bj) in b.iter().enumerate() {
            out[i + j] += ai * bj;
        }
    }
    out
}

/// Monic polynomial with the given roots; complex roots must come in
/// conjugate pairs for the result to be real (the imaginary parts are dropped).
pub fn poly_from_roots(roots: &[Complex<f64>]) -> Vec<f64> {
    let mut coefficients = vec![Complex::new(1.0, 0.0)];
    for &root in roots {
        let mut next = vec![Complex::new(0.0, 0.0); coefficients.len() + 1];
        for (i, &c) in coefficients.iter().enumerate() {
            next[i] += c;
            next[i + 1] -= c * root;
        }
        coefficients = next;
    }
    coefficients.iter().map(|c| c.re).collect()
}

/// Roots of a polynomial, as the eigenvalues of its balanced companion matrix.
/// Leading zeros are ignored; a constant polynomial has no roots.
pub fn poly_roots(coefficients: &[f64]) -> Vec<Complex<f64>> {
    let first = coefficients.iter().position(|&c| c != 0.0);
    let Some(first) = first else {
        return Vec::new();
    };
    let c = &coefficients[first..];
    let n = c.len() - 1;
    if n == 0 {
        return Vec::new();
    }
    let mut companion = DMatrix::zeros(n, n);
    for j in 0..n {
        companion[(0, j)] = -c[j + 1] / c[0];
    }
    for i in 1..n {
        companion[(i, i - 1)] = 1.0;
    }
    crate::state_space::eigenvalues(&companion)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roots_of_known_polynomial() {
        // (s + 1)(s + 2)(s^2 + 2s + 5): roots -1, -2, -1 ± 2j.
        let p = poly_mul(&poly_mul(&[1.0, 1.0], &[1.0, 2.0]), &[1.0, 2.0, 5.0]);
        let roots = poly_roots(&p);
        assert_eq!(roots.len(), 4);
        for (re, im) in [(-2.0, 0.0), (-1.0, -2.0), (-1.0, 0.0), (-1.0, 2.0)] {
            let expected = Complex::new(re, im);
            assert!(
                roots.iter().any(|r| (r - expected).norm() < 1e-9),
                "{expected} not in {roots:?}"
            );
        }
        let back = poly_from_roots(&roots);
        for (a, b) in back.iter().zip(&p) {
            assert!((a - b).abs() < 1e-9);
        }
    }

    #[test]
    fn eval_matches_hand_value() {
        let v = poly_eval(&[1.0, 0.0, 4.0], Complex::new(0.0, 2.0));
        assert!(v.norm() < 1e-12);
    }
}
