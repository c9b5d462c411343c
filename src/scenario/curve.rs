//! Initial curves and their discretization into rigid links of equal chord length.
//!
//! A curve is sampled densely into a polyline (parameter increasing); the rope's points are then
//! placed by walking chords of one common length `c` along it, each point the first crossing of
//! the circle of radius `c` around the previous one, with `c` found by bisection so that the
//! n-th point lands on the curve's end.

use crate::chain::Vec2;

use super::expr::Expr;

/// A validated initial curve.
#[derive(Debug, Clone, PartialEq)]
pub enum Curve {
    /// Straight segment from `from` to `to`.
    Line {
        /// Start point (parameter 0).
        from: Vec2,
        /// End point (parameter 1).
        to: Vec2,
    },
    /// `y = amplitude sin(2 pi x / wavelength + phase)` for `x` in `x_range`.
    Sine {
        /// x from .. to, m.
        x_range: [f64; 2],
        /// Amplitude, m.
        amplitude: f64,
        /// Wavelength, m.
        wavelength: f64,
        /// Phase, rad.
        phase: f64,
    },
    /// `y = coefficient x^2` for `x` in `x_range`.
    Parabola {
        /// x from .. to, m.
        x_range: [f64; 2],
        /// Coefficient, 1/m.
        coefficient: f64,
    },
    /// Circular arc around `center` from `from_rad` to `to_rad` (either direction).
    Arc {
        /// Center, m.
        center: Vec2,
        /// Radius, m.
        radius: f64,
        /// Start angle, rad.
        from_rad: f64,
        /// End angle, rad.
        to_rad: f64,
    },
    /// `(x(t), y(t))` for `t` in `t_range`.
    Parametric {
        /// x(t), m.
        x: Expr,
        /// y(t), m.
        y: Expr,
        /// Parameter range.
        t_range: [f64; 2],
    },
    /// A polyline given point by point (parameter: the index).
    Polyline(Vec<Vec2>),
}

/// Why a curve could not be discretized.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CurveError {
    /// The curve evaluates to a non-finite point.
    #[error("the curve is not finite at parameter {parameter}")]
    NotFinite {
        /// Where.
        parameter: f64,
    },
    /// The curve has no length.
    #[error("the curve has zero length")]
    ZeroLength,
    /// The chord walk could not place all the points (a curve folding back within a chord).
    #[error("could not place {links} equal chords along the curve (best end gap {gap:.3e} m)")]
    Chords {
        /// Links asked for.
        links: usize,
        /// Distance left between the last point and the curve's end.
        gap: f64,
    },
}

impl Curve {
    /// The point at parameter `s` in [0, 1] (mapped onto the curve's own range).
    pub fn at(&self, s: f64) -> Vec2 {
        let lerp = |r: [f64; 2]| r[0] + (r[1] - r[0]) * s;
        match self {
            Curve::Line { from, to } => from + (to - from) * s,
            Curve::Sine {
                x_range,
                amplitude,
                wavelength,
                phase,
            } => {
                let x = lerp(*x_range);
                Vec2::new(
                    x,
                    amplitude * (2.0 * std::f64::consts::PI * x / wavelength + phase).sin(),
                )
            }
            Curve::Parabola {
                x_range,
                coefficient,
            } => {
                let x = lerp(*x_range);
                Vec2::new(x, coefficient * x * x)
            }
            Curve::Arc {
                center,
                radius,
                from_rad,
                to_rad,
            } => {
                let a = from_rad + (to_rad - from_rad) * s;
                center + Vec2::new(a.cos(), a.sin()) * *radius
            }
            Curve::Parametric { x, y, t_range } => {
                let t = lerp(*t_range);
                Vec2::new(x.eval(t), y.eval(t))
            }
            Curve::Polyline(pts) => {
                let f = s.clamp(0.0, 1.0) * (pts.len() - 1) as f64;
                let i = (f.floor() as usize).min(pts.len() - 2);
                pts[i] + (pts[i + 1] - pts[i]) * (f - i as f64)
            }
        }
    }

    /// A dense polyline along the curve, parameter increasing.
    pub fn sample(&self, links: usize) -> Result<Vec<Vec2>, CurveError> {
        let pts: Vec<Vec2> = match self {
            Curve::Polyline(p) => p.clone(),
            Curve::Line { from, to } => vec![*from, *to],
            _ => {
                let m = (64 * links).max(4096);
                (0..=m).map(|i| self.at(i as f64 / m as f64)).collect()
            }
        };
        if let Some(i) = pts
            .iter()
            .position(|p| !(p.x.is_finite() && p.y.is_finite()))
        {
            return Err(CurveError::NotFinite {
                parameter: i as f64 / (pts.len() - 1).max(1) as f64,
            });
        }
        Ok(pts)
    }
}

/// Where `n` chords of length `c` end along `poly`: the points (n + 1 at most) and the arc
/// length position of the last one; `None` when the walk runs off the end first.
fn walk(poly: &[Vec2], cum: &[f64], c: f64, n: usize, out: &mut Vec<Vec2>) -> Option<f64> {
    out.clear();
    out.push(poly[0]);
    let mut seg = 0;
    let mut s0 = 0.0;
    let mut p = poly[0];
    for _ in 0..n {
        let mut found = None;
        while seg + 1 < poly.len() {
            let a = poly[seg];
            let d = poly[seg + 1] - a;
            // |a + s d - p|^2 = c^2, smallest root s >= s0. Solved around the foot of the
            // perpendicular from p (parameter t0, distance h) as s = t0 -+ sqrt(c^2 - h^2) / |d|:
            // the textbook discriminant cancels, its error |a - p|^2 / c^2 times round-off, when
            // the segment is long next to the chord (a line is one segment), and that noise
            // piled up over 10000 chords to a 1e-9 miss at the end.
            let w = a - p;
            let qa = d.norm_squared();
            if qa > 0.0 {
                let t0 = -w.dot(&d) / qa;
                let h2 = (w + d * t0).norm_squared();
                let disc = c * c - h2;
                if disc >= 0.0 {
                    let r = (disc / qa).sqrt();
                    for s in [t0 - r, t0 + r] {
                        if s >= s0 && s <= 1.0 {
                            found = Some(s);
                            break;
                        }
                    }
                }
            }
            if let Some(s) = found {
                s0 = s;
                p = a + d * s;
                break;
            }
            seg += 1;
            s0 = 0.0;
        }
        found?;
        out.push(p);
    }
    Some(cum[seg] + (cum[seg + 1] - cum[seg]) * s0)
}

/// `n` + 1 points along the curve, the first at its start, the last at its end, consecutive
/// points equally far apart (to round-off).
pub fn discretize(curve: &Curve, n: usize) -> Result<Vec<Vec2>, CurveError> {
    let poly = curve.sample(n)?;
    let mut cum = vec![0.0; poly.len()];
    for i in 1..poly.len() {
        cum[i] = cum[i - 1] + (poly[i] - poly[i - 1]).norm();
    }
    let total = cum[poly.len() - 1];
    if total.is_nan() || total <= 0.0 {
        return Err(CurveError::ZeroLength);
    }
    let end = poly[poly.len() - 1];
    let mut out = Vec::with_capacity(n + 1);
    let (mut lo, mut hi) = (0.0, total / n as f64 * (1.0 + 1e-12));
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        match walk(&poly, &cum, mid, n, &mut out) {
            Some(pos) if pos < total => lo = mid,
            _ => hi = mid,
        }
    }
    let gap = match walk(&poly, &cum, lo, n, &mut out) {
        Some(_) => (out[n] - end).norm(),
        None => f64::INFINITY,
    };
    // Each point of the walk is `a + d s` rounded, a few ulps of the coordinates' magnitude
    // `scale` off; the bisection on the one length c cancels what those errors share, not their
    // noise, so after n chords the end may miss by up to about n * 4 eps * scale. Allow 16 times
    // that (never less than 1e-9 of the length): at the largest count scenarios allow, 100000,
    // that is about 1.4e-9 * scale, while a walk that truly fails (the curve folding back within
    // a chord) misses by a good part of a chord, total / n >= 1e-5 * total.
    let scale = poly.iter().fold(total, |m, p| m.max(p.abs().max()));
    let tolerance = (16.0 * 4.0 * f64::EPSILON * n as f64 * scale).max(1e-9 * total);
    if gap.is_nan() || gap > tolerance {
        return Err(CurveError::Chords { links: n, gap });
    }
    out[n] = end;
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn chords(p: &[Vec2]) -> Vec<f64> {
        p.windows(2).map(|w| (w[1] - w[0]).norm()).collect()
    }

    #[test]
    fn equal_chords_on_every_curve() {
        let curves = [
            Curve::Line {
                from: Vec2::new(1.0, 0.0),
                to: Vec2::new(0.0, 2.0),
            },
            Curve::Sine {
                x_range: [0.0, 2.0],
                amplitude: 0.3,
                wavelength: 1.0,
                phase: 0.0,
            },
            Curve::Parabola {
                x_range: [-1.0, 1.0],
                coefficient: 0.8,
            },
            Curve::Arc {
                center: Vec2::zeros(),
                radius: 1.0,
                from_rad: 0.0,
                to_rad: 3.0,
            },
            Curve::Parametric {
                x: Expr::parse("t").unwrap(),
                y: Expr::parse("0.2*t^3").unwrap(),
                t_range: [-1.0, 1.0],
            },
            Curve::Polyline(vec![
                Vec2::zeros(),
                Vec2::new(1.0, 0.0),
                Vec2::new(1.0, 1.0),
            ]),
        ];
        for curve in &curves {
            let p = discretize(curve, 25).unwrap();
            assert_eq!(p.len(), 26);
            assert_eq!(p[0], curve.at(0.0));
            assert!((p[25] - curve.at(1.0)).norm() < 1e-15);
            let c = chords(&p);
            let (mn, mx) = c
                .iter()
                .fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(mx - mn < 1e-9 * mx, "{curve:?}: {mn} .. {mx}");
        }
    }

    #[test]
    fn arc_chords_match_the_closed_form() {
        // n equal chords of a circular arc of angle A: each is 2 R sin(A / 2n).
        let curve = Curve::Arc {
            center: Vec2::new(0.5, -0.5),
            radius: 2.0,
            from_rad: 1.0,
            to_rad: -1.0,
        };
        let p = discretize(&curve, 10).unwrap();
        let expected = 2.0 * 2.0 * (2.0f64 / 20.0).sin();
        for c in chords(&p) {
            assert!((c - expected).abs() < 1e-7, "{c} vs {expected}");
        }
    }

    /// Lines and polylines are one long segment per piece next to the chord: they split at the
    /// largest count a scenario allows, however far from the origin, into equal chords.
    #[test]
    fn long_segments_split_into_many_equal_chords() {
        let n = 100_000;
        let curves = [
            Curve::Line {
                from: Vec2::zeros(),
                to: Vec2::new(1.0, 0.0),
            },
            Curve::Line {
                from: Vec2::new(3.0, -2.0),
                to: Vec2::new(-4.0, 5.0),
            },
            Curve::Polyline(vec![
                Vec2::zeros(),
                Vec2::new(1.0, 0.0),
                Vec2::new(1.0, 1.0),
            ]),
        ];
        for curve in &curves {
            let p = discretize(curve, n).unwrap();
            assert_eq!(p.len(), n + 1);
            assert_eq!(p[n], curve.at(1.0));
            let c = chords(&p);
            let (mn, mx) = c
                .iter()
                .fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
            // Chords of 1e-5 .. 1e-4 m, equal to well under a nanometre.
            assert!(mx - mn < 1e-10, "{curve:?}: {mn} .. {mx}");
        }
    }

    #[test]
    fn degenerate_curves_are_refused() {
        let line = Curve::Line {
            from: Vec2::zeros(),
            to: Vec2::zeros(),
        };
        assert_eq!(discretize(&line, 3), Err(CurveError::ZeroLength));
        let bad = Curve::Parametric {
            x: Expr::parse("ln(t)").unwrap(),
            y: Expr::parse("t").unwrap(),
            t_range: [-1.0, 1.0],
        };
        assert!(matches!(
            discretize(&bad, 3),
            Err(CurveError::NotFinite { .. })
        ));
    }
}
