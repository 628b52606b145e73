//! Still poses of unknown orientation (method free, docs/calibration.md): the Gram matrix
//! G = S·Sᵀ and the offsets O from |S⁻¹(y − O)| = g alone.
//!
//! Only G and O are identifiable (docs/method.md §2b): G is parameterised by its lower Cholesky
//! factor L (S in the device frame, x′ along u, y′ in the plane of u and v), so the fit
//! has exactly the nine intrinsic degrees of freedom and the correction a = L⁻¹(y − O)
//! comes with it. For pose p with mean ȳ_p and the mean's covariance Σ_p:
//!
//! - a_p = L⁻¹(ȳ_p − O), n̂_p = a_p/|a_p|, w_p = L⁻ᵀn̂_p;
//! - residual r_p = |a_p| − g − b_p, in m/s²: the distance of the corrected reading from
//!   the sphere, not the algebraic |a|² − g², whose expectation is off by tr(C_p) (C_p =
//!   L⁻¹Σ_pL⁻ᵀ), a bias that grows as the signal-to-noise ratio falls;
//! - b_p = (tr C_p − n̂ᵀC_pn̂)/(2g): the second-order bias of |a_p| from the noise, taken
//!   out so that E[r_p] = 0 to that order;
//! - σ_p² = n̂ᵀC_pn̂ = w_pᵀΣ_pw_p (+ τ², the scatter of the poses beyond their noise when
//!   χ² demands it), and the fit minimises Σ r_p²/σ_p².
//!
//! ∂|a|/∂L_ij = −w_i·a_j and ∂|a|/∂O = −w, so the Jacobian is analytic. The minimiser is
//! the `levenberg-marquardt` crate (MINPACK's trust region); weights and biases are
//! refreshed between its runs. The covariance of (L, O) is (JᵀWJ)⁻¹ at the solution.

use crate::calibrate::budget::coverage_factor;
use crate::calibrate::still::{median, Interval, Verdict};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, Dyn, Matrix3, OMatrix, OVector, SMatrix, SVector, Vector3, U9};
use rotacal_shared::Channel;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};

/// The fit's parameters: L₀₀, L₁₀, L₁₁, L₂₀, L₂₁, L₂₂, O_u, O_v, O_w.
pub const PARAMS: usize = 9;

/// Condition numbers of the unit design above this are flagged (random poses: about 3 to
/// 10; poses on a hemisphere: some hundreds).
pub const WELL_CONDITIONED: f64 = 30.0;
/// Above this the poses leave G or O under-determined.
pub const SINGULAR: f64 = 1e6;
/// A pose's standard deviation of |a| is not taken below this fraction of g: below it
/// lies the round-off of noise-free data.
const ROUND_OFF: f64 = 1e-10;
/// Poses whose directions are closer than this (degrees) count as one orientation: a
/// second pose there adds almost nothing about G.
pub const DISTINCT_DEG: f64 = 3.0;
/// A pose whose residual is this many robust standard deviations from the others', and
/// beyond the normal quantile for its count, is taken out as not fitting.
const OUTLIER_ROBUST_Z: f64 = 5.0;

/// Which residual to minimise.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Residual {
    /// |a| − g − b, weighted by its variance (the default).
    #[default]
    Geometric,
    /// (|a|² − g²)/(2g) with the same weights: the peers' algebraic form, for comparison.
    Algebraic,
}

/// How the poses' scatter beyond their noise enters the covariance.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Scatter {
    /// τ added only when χ² exceeds its 99th percentile, then with P − 9 degrees of
    /// freedom (the default).
    #[default]
    Tested,
    /// τ² measured in every fit, signed and unbiased, (χ² − (P − 9))/S with S = Σ w_p(1 −
    /// h_p) (w_p the noise-only weight, h_p the pose's leverage), and added to the
    /// covariance even when it is negative; each property's degrees of freedom from τ²'s
    /// own variance (`--slow-noise`: docs/uncertainty.md, "Free poses under slow noise").
    Measured,
}

/// One pose: the mean of a still interval and its covariance.
#[derive(Clone, Debug, PartialEq)]
pub struct Pose {
    /// Its name.
    pub name: String,
    /// Mean u, v, w.
    pub mean: [f64; 3],
    /// Standard error of each channel's mean (the channels taken as independent).
    pub std_err: [f64; 3],
}

impl Pose {
    /// From a kept interval.
    pub fn from_interval(i: &Interval) -> Pose {
        Pose {
            name: i.name.clone(),
            mean: i.mean,
            std_err: i.std_err,
        }
    }
}

/// One pose in the result.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PoseResult {
    /// Its name.
    pub name: String,
    /// ĝ in the device frame, fitted: L⁻¹(ȳ − O) normalised.
    pub direction: [f64; 3],
    /// |a| − g − b, m/s².
    pub residual_ms2: f64,
    /// Its standard deviation, m/s² (noise and τ).
    pub residual_std_ms2: f64,
}

/// Why the poses cannot be fitted.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FreeError {
    /// Fewer distinct orientations than parameters.
    #[error(
        "{poses} still pose(s) in {distinct} distinct orientation(s) ({orientations}; poses \
         within {DISTINCT_DEG}° count as one): the nine intrinsic properties need at least \
         nine; add poses with gravity near {add} (x, y, z: the sensor's u, v, w axes)"
    )]
    TooFew {
        /// Poses.
        poses: usize,
        /// Distinct orientations among them.
        distinct: usize,
        /// Those orientations, named.
        orientations: String,
        /// Directions to add.
        add: String,
    },
    /// Poses on a circle or in a plane, or the like.
    #[error(
        "the {poses} poses leave G or O under-determined (condition number {cond:.3e}; \
         {why}): add poses with gravity near {add} (x, y, z: the sensor's u, v, w axes)"
    )]
    UnderDetermined {
        /// Poses.
        poses: usize,
        /// Condition number of the unit design.
        cond: f64,
        /// What the poses have in common.
        why: String,
        /// Directions to add.
        add: String,
    },
    /// The minimiser failed.
    #[error("the fit of G and O did not converge: {0}")]
    NoConvergence(String),
}

/// The result.
#[derive(Clone, Debug)]
pub struct FreeFit {
    /// S in the device frame: L, lower triangular, output units per m/s².
    pub l: [[f64; 3]; 3],
    /// O, output units.
    pub offsets: [f64; 3],
    /// Covariance of (S row-major, O), 12 × 12 (zeros where L is zero).
    pub cov: SMatrix<f64, 12, 12>,
    /// The poses fitted.
    pub poses: Vec<PoseResult>,
    /// Poses taken out as not fitting: (name, verdict).
    pub rejected: Vec<(String, Verdict)>,
    /// χ² of the fit with the noise alone (τ = 0), and its degrees of freedom P − 9.
    pub chi2: f64,
    /// P − 9.
    pub dof: usize,
    /// Scatter of the poses beyond their noise, m/s² (0 unless χ² exceeds its 99th
    /// percentile; with [`Scatter::Measured`], √max(τ², 0)).
    pub tau_ms2: f64,
    /// With [`Scatter::Measured`]: the signed estimate τ² = (χ² − (P − 9))/S, m²/s⁴, as
    /// used (raised where it would leave a negative variance), and its variance.
    pub tau2_measured: Option<(f64, f64)>,
    /// How `cov` grows per unit τ² (m²/s⁴) at the noise-only weights: (JᵀWJ)⁻¹·JᵀW²J·(JᵀWJ)⁻¹.
    pub cov_per_tau2: SMatrix<f64, 12, 12>,
    /// Per pose, its weight w_p = 1/σ_p² (m⁻²s⁴) and 1 − h_p, h_p its leverage.
    pub scatter_design: Vec<(f64, f64)>,
    /// Degrees of freedom behind the covariance: P − 9 with τ, else infinite; with
    /// [`Scatter::Measured`], the fewest among the parameters ([`scatter_dof`]).
    pub nu: f64,
    /// Coverage factor at `nu`.
    pub k: f64,
    /// Condition number of the unit design.
    pub condition_number: f64,
    /// When flagged, the directions to add.
    pub suggestion: Option<String>,
    /// What the user should know, each a sentence.
    pub notes: Vec<String>,
    /// The residual used.
    pub residual: Residual,
}

impl FreeFit {
    /// Takes the common part of the scatter τ out of the offsets, where another term
    /// stands for it (docs/uncertainty.md, "Free poses under slow noise").
    ///
    /// τ counts each pose's error as independent, isotropic in specific force: ε_p with
    /// τ² per axis. Their mean over the P poses, ε̄ (τ²/P per axis), moves every pose's
    /// reading alike, by L·ε̄, which the fit takes wholly into O; so τ gives O the
    /// covariance (τ²/P)·L·Lᵀ from ε̄ beside what the poses' differences give. When the
    /// poses' errors are the bias's slow wander, their mean over the poses is the
    /// `bias_wander` line's (the poses' mean bias against the record's), and ε̄ must not
    /// count twice. Gives whether it was taken out: not when τ = 0, or when what is left
    /// would not be a covariance (a negative eigenvalue).
    pub fn take_out_common_scatter(&mut self) -> bool {
        let p = self.poses.len() as f64;
        let tau2 = self
            .tau2_measured
            .map_or(self.tau_ms2.powi(2), |(t2, _)| t2);
        if tau2 == 0.0 || p == 0.0 {
            return false;
        }
        let l = Matrix3::from(self.l).transpose();
        let unit = l * l.transpose() / p;
        let (mut cov, mut per) = (self.cov, self.cov_per_tau2);
        let mut block = cov.fixed_view_mut::<3, 3>(9, 9);
        block -= unit * tau2;
        let mut block = per.fixed_view_mut::<3, 3>(9, 9);
        block -= unit;
        let psd = is_covariance(&cov);
        if psd {
            self.cov = cov;
            self.cov_per_tau2 = per;
        }
        psd
    }
}

/// L from the parameters.
fn l_of(x: &SVector<f64, PARAMS>) -> Matrix3<f64> {
    let [l00, l10, l11, l20, l21, l22, ..]: [f64; PARAMS] = (*x).into();
    Matrix3::new(l00, 0.0, 0.0, l10, l11, 0.0, l20, l21, l22)
}

/// O from the parameters.
fn offsets_of(x: &SVector<f64, PARAMS>) -> [f64; 3] {
    let [.., o_u, o_v, o_w]: [f64; PARAMS] = (*x).into();
    [o_u, o_v, o_w]
}

/// p_i·q_j for each of L's parameters L_ij, in their order.
fn lower_products(p: &Vector3<f64>, q: &Vector3<f64>) -> SVector<f64, 6> {
    let ([p0, p1, p2], [q0, q1, q2]): ([f64; 3], [f64; 3]) = ((*p).into(), (*q).into());
    SVector::from([p0 * q0, p1 * q0, p1 * q1, p2 * q0, p2 * q1, p2 * q2])
}

/// The parameters from L's six and O's three.
fn join(l: [f64; 6], o: [f64; 3]) -> [f64; PARAMS] {
    let [l00, l10, l11, l20, l21, l22] = l;
    let [o_u, o_v, o_w] = o;
    [l00, l10, l11, l20, l21, l22, o_u, o_v, o_w]
}

/// The parameters' places among the 12 of (S row-major, O), `zero` where L is zero.
fn to_twelve<T: Copy>(x: [T; PARAMS], zero: T) -> [T; 12] {
    let [l00, l10, l11, l20, l21, l22, o_u, o_v, o_w] = x;
    [
        l00, zero, zero, l10, l11, zero, l20, l21, l22, o_u, o_v, o_w,
    ]
}

/// A pose's corrected mean at θ: a = L⁻¹(ȳ − O), q = |a|, n̂ = a/q and w = L⁻ᵀn̂ (what
/// the residual and its Jacobian need).
struct Geometry {
    l: Matrix3<f64>,
    a: Vector3<f64>,
    q: f64,
    n: Vector3<f64>,
    w: Vector3<f64>,
}

fn geometry(x: &SVector<f64, PARAMS>, pose: &Pose) -> Option<Geometry> {
    let l = l_of(x);
    let o = Vector3::from(offsets_of(x));
    let a = l.solve_lower_triangular(&(Vector3::from(pose.mean) - o))?;
    let q = a.norm();
    if !(q.is_finite() && q > 0.0) {
        return None;
    }
    let n = a / q;
    let w = l.transpose().solve_upper_triangular(&n)?;
    Some(Geometry { l, a, q, n, w })
}

/// Per pose at θ, its noise's effect on |a|: the geometry, σ² = n̂ᵀCn̂ (without τ) and
/// the bias b = (tr C − n̂ᵀCn̂)/(2g), C = L⁻¹ΣL⁻ᵀ.
struct At {
    geo: Geometry,
    var: f64,
    bias: f64,
}

fn at(x: &SVector<f64, PARAMS>, pose: &Pose, g: f64) -> Option<At> {
    let geo = geometry(x, pose)?;
    let linv = geo.l.solve_lower_triangular(&Matrix3::identity())?;
    let se2 = pose.std_err.map(|s| s * s);
    let var = geo.w.iter().zip(&se2).map(|(w, s)| w * w * s).sum::<f64>();
    // Row by row: Lᵀ column-major is L row-major, each row against se2 again.
    let tr = linv
        .transpose()
        .iter()
        .zip(se2.iter().cycle())
        .map(|(l, s)| l.powi(2) * s)
        .sum::<f64>();
    Some(At {
        geo,
        var,
        bias: (tr - var) / (2.0 * g),
    })
}

/// Cov(|a|, ∂|a|/∂θ) of one pose to second order in its noise: with C = L⁻¹ΣL⁻ᵀ,
/// m = C·n̂ and v = L⁻ᵀ(I − n̂n̂ᵀ)m/|a|, it is −v_k for O_k and −a_j·v_i − w_i·m_j for L_ij.
fn score_cov(x: &SVector<f64, PARAMS>, pose: &Pose) -> Option<SVector<f64, 9>> {
    let Geometry { l, a, q, n, w } = geometry(x, pose)?;
    let linv = l.solve_lower_triangular(&Matrix3::identity())?;
    let sigma = Matrix3::from_diagonal(&Vector3::from(pose.std_err.map(|s| s * s)));
    let c = linv * sigma * linv.transpose();
    let m = c * n;
    let proj = Matrix3::identity() - n * n.transpose();
    let v = linv.transpose() * proj * m / q;
    // −a_j·v_i − w_i·m_j: the negated product is the product of the negated factor.
    let l = -lower_products(&v, &a) - lower_products(&w, &m);
    Some(SVector::from(join(l.into(), (-v).into())))
}

/// The least-squares problem at fixed weights and biases.
struct Problem<'a> {
    x: OVector<f64, U9>,
    poses: &'a [Pose],
    g: f64,
    /// Per pose: 1/σ and b.
    weight: Vec<(f64, f64)>,
    residual: Residual,
}

impl Problem<'_> {
    /// Each pose's weighted residual and Jacobian row (none if a pose has no weight).
    fn rows(&self) -> Option<Vec<(f64, [f64; PARAMS])>> {
        if self.weight.len() < self.poses.len() {
            return None;
        }
        self.poses
            .iter()
            .zip(&self.weight)
            .map(|(p, w)| self.row(p, *w))
            .collect()
    }

    fn row(&self, p: &Pose, (inv_sd, bias): (f64, f64)) -> Option<(f64, [f64; PARAMS])> {
        let s = geometry(&self.x, p)?;
        let (r, scale) = match self.residual {
            Residual::Geometric => (s.q - self.g - bias, 1.0),
            Residual::Algebraic => ((s.q * s.q - self.g * self.g) / (2.0 * self.g), s.q / self.g),
        };
        // −w_i·a_j: the negated product is the product of the negated factor.
        let l = lower_products(&s.w, &s.a).map(|p| -p * scale * inv_sd);
        let o = s.w.map(|w| -w * scale * inv_sd);
        Some((r * inv_sd, join(l.into(), o.into())))
    }
}

impl LeastSquaresProblem<f64, Dyn, U9> for Problem<'_> {
    type ResidualStorage = nalgebra::VecStorage<f64, Dyn, nalgebra::U1>;
    type JacobianStorage = nalgebra::VecStorage<f64, Dyn, U9>;
    type ParameterStorage = nalgebra::ArrayStorage<f64, 9, 1>;

    fn set_params(&mut self, x: &OVector<f64, U9>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> OVector<f64, U9> {
        self.x
    }

    fn residuals(&self) -> Option<OVector<f64, Dyn>> {
        let r = self.rows()?.into_iter().map(|(r, _)| r).collect();
        Some(OVector::<f64, Dyn>::from_vec(r))
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U9>> {
        let rows = self.rows()?;
        let n = rows.len();
        Some(OMatrix::<f64, Dyn, U9>::from_row_iterator(
            n,
            rows.into_iter().flat_map(|(_, j)| j),
        ))
    }
}

/// A start: the sphere through the pose means (|y − c|² = R², linear in c and
/// R² − |c|²), so L = (R/g)·I and O = c.
fn start(poses: &[Pose], g: f64) -> Option<SVector<f64, 9>> {
    let mut m = nalgebra::Matrix4::zeros();
    let mut b = nalgebra::Vector4::zeros();
    for p in poses {
        let y = p.mean;
        let h = nalgebra::Vector4::new(2.0 * y[0], 2.0 * y[1], 2.0 * y[2], 1.0);
        m += h * h.transpose();
        b += h * (y[0] * y[0] + y[1] * y[1] + y[2] * y[2]);
    }
    let [c0, c1, c2, c3]: [f64; 4] = (m.try_inverse()? * b).into();
    let r2 = c3 + c0 * c0 + c1 * c1 + c2 * c2;
    let s = (r2.max(0.0)).sqrt() / g;
    (s > 0.0).then(|| SVector::from([s, 0.0, s, 0.0, 0.0, s, c0, c1, c2]))
}

/// The unit design: the Jacobian rows of L = I, O = 0, g = 1 at unit directions.
fn unit_row(n: &[f64; 3]) -> [f64; PARAMS] {
    let v = Vector3::from(*n);
    join(lower_products(&v, &v).into(), *n)
}

/// The condition number of the unit design rows (padded with zero rows to nine).
fn cond_of(rows: &[[f64; PARAMS]]) -> f64 {
    let padded = rows.iter().flatten().copied().chain(std::iter::repeat(0.0));
    let m = DMatrix::from_row_iterator(rows.len().max(PARAMS), PARAMS, padded);
    let (smin, smax, _) = crate::calibrate::poses::weakest(m);
    if smin > smax * 1e-15 {
        smax / smin
    } else {
        f64::INFINITY
    }
}

/// Candidate directions to suggest: the axes, the edges and the corners of a cube.
fn candidates() -> Vec<([f64; 3], String)> {
    let axis = ["x", "y", "z"];
    let mut out = Vec::new();
    for (a, name) in axis.iter().enumerate() {
        for s in [1.0, -1.0] {
            let v = std::array::from_fn(|k| if k == a { s } else { 0.0 });
            out.push((v, format!("{}{}", if s > 0.0 { "+" } else { "−" }, name)));
        }
    }
    for (a, name_a) in axis.iter().enumerate() {
        for (b, name_b) in axis.iter().enumerate().skip(a + 1) {
            for (sa, sb) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                let v = std::array::from_fn(|k| match k {
                    k if k == a => sa / 2f64.sqrt(),
                    k if k == b => sb / 2f64.sqrt(),
                    _ => 0.0,
                });
                let sign = |s: f64| if s > 0.0 { "+" } else { "−" };
                out.push((
                    v,
                    format!("({}{}{}{})/√2", sign(sa), name_a, sign(sb), name_b),
                ));
            }
        }
    }
    out
}

/// log det(JᵀJ + εI) of unit design rows: the D-optimal criterion (ε keeps it finite
/// while the rows do not yet determine every parameter).
fn log_det(rows: &[[f64; PARAMS]]) -> f64 {
    let mut m = SMatrix::<f64, PARAMS, PARAMS>::identity() * 1e-6;
    for r in rows {
        let v = SVector::<f64, PARAMS>::from_column_slice(r);
        m += v * v.transpose();
    }
    m.symmetric_eigenvalues()
        .iter()
        .map(|l| l.max(1e-300).ln())
        .sum()
}

/// Directions that would make the design well conditioned, greedily: each time the
/// candidate (an axis, edge or corner of a cube) that raises log det(JᵀJ) most, until the
/// design is well conditioned (at most six). Named in the device frame: x′ ≈ u's axis,
/// y′ ≈ v's, z′ ≈ w's.
fn suggest(rows: &[[f64; PARAMS]]) -> String {
    let mut rows = rows.to_vec();
    let mut picked: Vec<String> = Vec::new();
    let cands = candidates();
    for _ in 0..6 {
        if rows.len() >= PARAMS && cond_of(&rows) <= WELL_CONDITIONED {
            break;
        }
        let best = cands
            .iter()
            .map(|(v, name)| {
                let mut r = rows.clone();
                r.push(unit_row(v));
                (log_det(&r), v, name)
            })
            .max_by(|a, b| a.0.total_cmp(&b.0));
        match best {
            Some((_, v, name)) => {
                rows.push(unit_row(v));
                picked.push(name.clone());
            }
            None => break,
        }
    }
    match picked.split_last() {
        None => "other directions".into(),
        Some((only, [])) => only.clone(),
        Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
    }
}

/// The poses' distinct orientations: (first direction of the group, count), grouping
/// directions within [`DISTINCT_DEG`] of a group's first.
fn distinct(dirs: &[[f64; 3]]) -> Vec<([f64; 3], usize)> {
    let cos = DISTINCT_DEG.to_radians().cos();
    let mut out: Vec<([f64; 3], usize)> = Vec::new();
    for d in dirs {
        match out
            .iter_mut()
            .find(|(c, _)| c[0] * d[0] + c[1] * d[1] + c[2] * d[2] >= cos)
        {
            Some(c) => c.1 += 1,
            None => out.push((*d, 1)),
        }
    }
    out
}

/// A direction as text: the nearest axis, edge or corner of a cube when within 10°,
/// else the vector.
pub fn name_direction(d: &[f64; 3]) -> String {
    let near = candidates()
        .into_iter()
        .map(|(v, n)| (v[0] * d[0] + v[1] * d[1] + v[2] * d[2], n))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    match near {
        Some((c, n)) if c >= DISTINCT_DEG.to_radians().cos() => format!("near {n}"),
        _ => format!("({:.2}, {:.2}, {:.2})", d[0], d[1], d[2]),
    }
}

/// Pose means in one plane (smallest spread across it below [`PLANAR`] of the largest):
/// their orientations lie on one circle, and no ellipsoid is fixed by them.
fn planar(poses: &[Pose]) -> Option<FreeError> {
    let n = poses.len() as f64;
    if poses.len() < 3 {
        return None;
    }
    let [c_u, c_v, c_w] =
        Channel::ALL.map(|ch| poses.iter().map(|p| *ch.of(&p.mean)).sum::<f64>() / n);
    let centred = poses.iter().flat_map(|p| {
        let [u, v, w] = p.mean;
        [u - c_u, v - c_v, w - c_w]
    });
    let m = DMatrix::from_row_iterator(poses.len(), 3, centred);
    let svd = m.svd(false, true);
    let sv = &svd.singular_values;
    let (imin, smin) = sv
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, s)| (i, *s))?;
    let smax = sv.iter().fold(0.0f64, |a, b| a.max(*b));
    if smin > PLANAR * smax {
        return None;
    }
    let normal = svd
        .v_t
        .as_ref()
        .map(|vt| [vt[(imin, 0)], vt[(imin, 1)], vt[(imin, 2)]])?;
    let flip = normal.map(|v| -v);
    Some(FreeError::UnderDetermined {
        poses: poses.len(),
        cond: f64::INFINITY,
        why: format!(
            "their readings lie in one plane (spread across it {:.1e} of that along it), so \
             their orientations are on one circle, as turning about one axis gives",
            smin / smax
        ),
        add: format!(
            "{} and {}",
            name_direction(&normal).trim_start_matches("near "),
            name_direction(&flip).trim_start_matches("near ")
        ),
    })
}

/// Pose means spread less than this across their best plane, relative to along it, count
/// as planar (about 1° off a circle of poses).
pub const PLANAR: f64 = 0.02;

/// What degenerate poses have in common, for the message.
fn why_degenerate(dirs: &[[f64; 3]]) -> String {
    // The directions' plane: the smallest singular vector of [n, 1].
    let rows = dirs.iter().flat_map(|&[x, y, z]| [x, y, z, 1.0]);
    let padded = rows.chain(std::iter::repeat(0.0));
    let m = DMatrix::from_row_iterator(dirs.len().max(4), 4, padded);
    let svd = m.svd(false, true);
    let smin = svd
        .singular_values
        .iter()
        .fold(f64::INFINITY, |a, b| a.min(*b));
    if smin < 1e-3 * (dirs.len() as f64).sqrt() {
        let great = svd.v_t.as_ref().and_then(|vt| {
            let i = svd.singular_values.iter().position(|s| *s == smin)?;
            Some(vt[(i, 3)].abs() < 1e-2 * (vt[(i, 0)].hypot(vt[(i, 1)]).hypot(vt[(i, 2)])))
        });
        return match great {
            Some(true) => {
                "their directions lie on one great circle, as a rotation about one axis gives"
                    .into()
            }
            _ => "their directions lie on one circle (one plane cuts them all)".into(),
        };
    }
    "their directions do not span the ellipsoid".into()
}

/// Fit G and O to the poses in gravity `g`.
pub fn fit(poses: &[Pose], g: f64, residual: Residual) -> Result<FreeFit, FreeError> {
    fit_with(poses, g, residual, Scatter::Tested)
}

/// Fit G and O to the poses in gravity `g`, the scatter beyond the noise as `scatter` says.
pub fn fit_with(
    poses: &[Pose],
    g: f64,
    residual: Residual,
    scatter: Scatter,
) -> Result<FreeFit, FreeError> {
    let mut poses: Vec<Pose> = poses.to_vec();
    let mut rejected = Vec::new();
    let mut notes = Vec::new();
    loop {
        if let Some(e) = planar(&poses) {
            return Err(e);
        }
        let x0 = start(&poses, g);
        // Directions as the start sees them (the sphere fit): enough to judge the geometry.
        let dirs: Vec<[f64; 3]> = poses
            .iter()
            .map(|p| {
                let [c_u, c_v, c_w] = x0.map_or([0.0; 3], |x| offsets_of(&x));
                let [u, v, w] = p.mean;
                let d = [u - c_u, v - c_v, w - c_w];
                let n = d.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
                d.map(|v| v / n)
            })
            .collect();
        let rows: Vec<[f64; PARAMS]> = dirs.iter().map(unit_row).collect();
        let clusters = distinct(&dirs);
        if clusters.len() < PARAMS {
            let centres: Vec<[f64; 3]> = clusters.iter().map(|c| c.0).collect();
            let one_each: Vec<[f64; PARAMS]> = centres.iter().map(unit_row).collect();
            return Err(FreeError::TooFew {
                poses: poses.len(),
                distinct: clusters.len(),
                orientations: clusters
                    .iter()
                    .map(|(c, n)| format!("{} ×{n}", name_direction(c)))
                    .collect::<Vec<_>>()
                    .join(", "),
                add: suggest(&one_each),
            });
        }
        let cond = cond_of(&rows);
        let Some(x0) = x0.filter(|_| cond <= SINGULAR) else {
            return Err(FreeError::UnderDetermined {
                poses: poses.len(),
                cond,
                why: why_degenerate(&dirs),
                add: suggest(&rows),
            });
        };
        let mut fit = solve(&poses, g, residual, x0, 0.0)?;
        fit.condition_number = cond;
        if cond > WELL_CONDITIONED {
            let add = suggest(&rows);
            notes.push(format!(
                "the poses are badly conditioned (condition number {cond:.1}, above \
                 {WELL_CONDITIONED}): add poses with gravity near {add}"
            ));
            fit.suggestion = Some(add);
        }
        // A pose that does not fit: far out both against its own noise (Bonferroni over
        // the poses) and against the others' scatter (robust).
        let z: Vec<f64> = fit
            .poses
            .iter()
            .map(|p| p.residual_ms2 / p.residual_std_ms2.max(1e-300))
            .collect();
        let mut abs_dev: Vec<f64> = {
            let mut r: Vec<f64> = fit.poses.iter().map(|p| p.residual_ms2).collect();
            let m = median(&mut r);
            fit.poses
                .iter()
                .map(|p| (p.residual_ms2 - m).abs())
                .collect()
        };
        let mad = 1.4826 * median(&mut abs_dev);
        let z_crit = Normal::new(0.0, 1.0)
            .map(|n| n.inverse_cdf(1.0 - 0.005 / poses.len() as f64))
            .unwrap_or(4.0);
        let worst = z
            .iter()
            .zip(&fit.poses)
            .enumerate()
            .max_by(|a, b| a.1 .0.abs().total_cmp(&b.1 .0.abs()))
            .map(|(i, (v, p))| (i, *v, p));
        let significant = fit.dof > 0 && chi2_p(fit.chi2, fit.dof) < 0.01;
        if let Some((i, zi, p)) = worst {
            let r = p.residual_ms2;
            if significant
                && zi.abs() > z_crit
                && (r.abs() > OUTLIER_ROBUST_Z * mad)
                && poses.len() > PARAMS
            {
                rejected.push((
                    p.name.clone(),
                    Verdict::DoesNotFit {
                        residual_ms2: r,
                        z: zi,
                    },
                ));
                poses.remove(i);
                continue;
            }
        }
        if scatter == Scatter::Measured && fit.dof > 0 {
            measure_scatter(&mut fit, &mut notes);
        } else if significant {
            // Scatter beyond the noise, when χ² demands it.
            let tau = tau_for(&fit, fit.dof);
            let mut with = solve(&poses, g, residual, fit_params(&fit), tau)?;
            with.condition_number = fit.condition_number;
            with.suggestion = fit.suggestion.clone();
            with.chi2 = fit.chi2;
            notes.push(format!(
                "the poses scatter beyond their noise (χ² = {:.1} on {} degrees of freedom, \
                 p < 0.01): a scatter τ = {tau:.3e} m/s² per pose is added to each pose's \
                 variance (estimated so that χ² equals its degrees of freedom), and the \
                 coverage factor is Student's t at {} degrees of freedom",
                fit.chi2, fit.dof, fit.dof
            ));
            fit = with;
        }
        fit.rejected = rejected;
        fit.notes = notes;
        return Ok(fit);
    }
}

/// [`Scatter::Measured`]: τ² from the noise-only χ², signed, into the covariance, and its
/// variance, Var χ² / S² with Var χ² = Σ 2(1 − h_p)(1 + τ₊²w_p)² (each residual's share,
/// normal, the leverages taken as independent). A negative τ² that would leave a property
/// a negative variance is taken up to where none is (bisection).
fn measure_scatter(fit: &mut FreeFit, notes: &mut Vec<String>) {
    let s: f64 = fit.scatter_design.iter().map(|(w, q)| w * q).sum();
    if !(s.is_finite() && s > 0.0) {
        return;
    }
    let dof = fit.dof as f64;
    let estimate = (fit.chi2 - dof) / s;
    let psd = |t2: f64| is_covariance(&(fit.cov + fit.cov_per_tau2 * t2));
    let mut tau2 = estimate;
    if !psd(tau2) {
        let (mut lo, mut hi) = (tau2, 0.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if psd(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        tau2 = hi;
    }
    let t2p = tau2.max(0.0);
    let var_chi2: f64 = fit
        .scatter_design
        .iter()
        .map(|(w, q)| 2.0 * q * (1.0 + t2p * w).powi(2))
        .sum();
    let var_tau2 = var_chi2 / (s * s);
    fit.cov += fit.cov_per_tau2 * tau2;
    fit.tau_ms2 = t2p.sqrt();
    fit.tau2_measured = Some((tau2, var_tau2));
    // The fewest degrees of freedom among the parameters, for the correction's k.
    fit.nu = fit
        .cov
        .diagonal()
        .iter()
        .zip(fit.cov_per_tau2.diagonal().iter())
        .filter(|(_, c)| **c > 0.0)
        .map(|(u2, c)| scatter_dof(*u2, *c, (tau2, var_tau2)))
        .fold(f64::INFINITY, f64::min);
    fit.k = coverage_factor(fit.nu);
    notes.push(format!(
        "--slow-noise: the poses' scatter beyond their noise is measured in every fit, not \
         only when χ² is significant: τ² = {estimate:.3e} m²/s⁴ (standard deviation \
         {:.1e}) from χ² = {:.1} on {} degrees of freedom, added to each pose's variance \
         whatever its sign{}; each property's degrees of freedom from τ²'s variance",
        var_tau2.sqrt(),
        fit.chi2,
        fit.dof,
        if tau2 == estimate {
            String::new()
        } else {
            format!(" (taken at {tau2:.3e}, where no property's variance is negative)")
        }
    ));
}

/// Whether `cov` is a covariance: no eigenvalue below −10⁻¹² of its largest variance.
fn is_covariance(cov: &SMatrix<f64, 12, 12>) -> bool {
    let scale = cov.diagonal().amax().max(f64::MIN_POSITIVE);
    cov.symmetric_eigenvalues()
        .iter()
        .all(|e| *e >= -1e-12 * scale)
}

/// The degrees of freedom of a variance `u2` that holds `c`·τ², τ² = `tau2` of variance
/// `var_tau2`: 2V²/Var(u²) (infinite where τ² is exact), V the larger of u² and the
/// variance the poses' noise alone gives, u² − c·τ². A negative τ² takes u² below what the
/// noise alone shows; with u² itself in ν, the sessions with the smallest U would get the
/// largest k (as for the rotation budget's `fits` line, docs/uncertainty.md).
pub fn scatter_dof(u2: f64, c: f64, (tau2, var_tau2): (f64, f64)) -> f64 {
    let v = c * c * var_tau2;
    let floor = u2.max(u2 - c * tau2);
    if v > 0.0 {
        2.0 * floor * floor / v
    } else {
        f64::INFINITY
    }
}

/// Upper tail probability of χ² with `dof` degrees of freedom.
fn chi2_p(chi2: f64, dof: usize) -> f64 {
    ChiSquared::new(dof as f64).map_or(1.0, |d| 1.0 - d.cdf(chi2))
}

fn fit_params(f: &FreeFit) -> SVector<f64, PARAMS> {
    let [[l00, _, _], [l10, l11, _], [l20, l21, l22]] = f.l;
    SVector::from(join([l00, l10, l11, l20, l21, l22], f.offsets))
}

/// τ such that Σ r²/(σ² + τ²) = dof (bisection on τ²).
fn tau_for(f: &FreeFit, dof: usize) -> f64 {
    let chi = |t2: f64| {
        f.poses
            .iter()
            .map(|p| p.residual_ms2.powi(2) / (p.residual_std_ms2.powi(2) + t2))
            .sum::<f64>()
    };
    let target = dof as f64;
    let mut hi = f
        .poses
        .iter()
        .map(|p| p.residual_ms2.powi(2))
        .fold(0.0, f64::max)
        .max(1e-300);
    let mut lo = 0.0;
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (0.5 * (lo + hi)).sqrt()
}

/// The weighted fit from `x0` with scatter `tau` (m/s²): weights and biases refreshed
/// between minimiser runs until the parameters settle.
fn solve(
    poses: &[Pose],
    g: f64,
    residual: Residual,
    x0: SVector<f64, 9>,
    tau: f64,
) -> Result<FreeFit, FreeError> {
    let mut x = x0;
    // Noise-free poses (simulated) have no variance: every pose then weighs the same.
    let weights_at = |x: &SVector<f64, 9>| -> Result<Vec<(f64, f64)>, FreeError> {
        let mut w = Vec::with_capacity(poses.len());
        for p in poses {
            let s = at(x, p, g)
                .ok_or_else(|| FreeError::NoConvergence("a pose maps to zero".into()))?;
            w.push((s.var, s.bias));
        }
        let noiseless = w.iter().all(|(v, _)| *v <= 0.0);
        Ok(w.into_iter()
            .map(|(v, b)| {
                let var = if noiseless {
                    1.0
                } else {
                    v.max((ROUND_OFF * g).powi(2)) + tau * tau
                };
                (
                    1.0 / var.sqrt(),
                    if residual == Residual::Geometric {
                        b
                    } else {
                        0.0
                    },
                )
            })
            .collect())
    };
    let mut problem = Problem {
        x,
        poses,
        g,
        weight: weights_at(&x)?,
        residual,
    };
    // Up to six refreshes of the weights and biases, each followed by a run; the last run
    // after the parameters have settled.
    let mut last = false;
    for pass in 0..7 {
        let (solved, report) = LevenbergMarquardt::new().minimize(problem);
        if !report.termination.was_successful() {
            return Err(FreeError::NoConvergence(format!(
                "{:?}",
                report.termination
            )));
        }
        problem = solved;
        let moved = (problem.x - x).norm() / x.norm().max(1e-300);
        x = problem.x;
        if last {
            break;
        }
        problem.weight = weights_at(&x)?;
        last = moved < 1e-12 || pass == 5;
    }
    let j = problem
        .jacobian()
        .ok_or_else(|| FreeError::NoConvergence("no Jacobian at the solution".into()))?;
    // `jacobian` answers only with a weight for every pose: the loops below pair them.
    let jtj = j.tr_mul(&j);
    let cov9 = jtj
        .try_inverse()
        .ok_or_else(|| FreeError::NoConvergence("singular normal matrix".into()))?;
    if residual == Residual::Geometric {
        // The Jacobian depends on the noisy mean too, so E[r·J] ≠ 0 even with E[r] = 0:
        // the estimating equation's expectation β = Σ Cov(r_p, J_p)/σ_p², to second order
        // in the noise, biases θ by −(JᵀWJ)⁻¹β. Taken out in one step.
        let mut beta = SVector::<f64, 9>::zeros();
        for (p, (inv_sd, _)) in poses.iter().zip(problem.weight.iter().copied()) {
            if let Some(c) = score_cov(&x, p) {
                beta += c * inv_sd * inv_sd;
            }
        }
        let step = cov9 * beta;
        problem.x += step;
        x = problem.x;
    }
    // For a scatter τ² beyond the weights: the sandwich (JᵀJ)⁻¹·JᵀWJ·(JᵀJ)⁻¹ with J's rows
    // already weighted by 1/σ_p (so JᵀWJ here is the unweighted Jacobian's JᵀW²J), each
    // pose's weight w_p = 1/σ_p², and its leverage h_p = j_pᵀ(JᵀJ)⁻¹j_p.
    let mut jwj = SMatrix::<f64, PARAMS, PARAMS>::zeros();
    let mut scatter_design = Vec::with_capacity(poses.len());
    for (row, (inv_sd, _)) in j.row_iter().zip(problem.weight.iter().copied()) {
        let r = row.transpose();
        let w = inv_sd * inv_sd;
        jwj += r * r.transpose() * w;
        scatter_design.push((w, 1.0 - (cov9 * r).dot(&r)));
    }
    // To (S row-major, O): each column, and the columns, spread to twelve with zeros.
    let twelve = |m: SMatrix<f64, PARAMS, PARAMS>| {
        let cols: [[f64; PARAMS]; PARAMS] = m.into();
        SMatrix::<f64, 12, 12>::from(to_twelve(cols.map(|c| to_twelve(c, 0.0)), [0.0; 12]))
    };
    let cov = twelve(cov9);
    let cov_per_tau2 = twelve(cov9 * jwj * cov9);
    let mut results = Vec::with_capacity(poses.len());
    let mut chi2 = 0.0;
    for (p, (inv_sd, bias)) in poses.iter().zip(problem.weight.iter().copied()) {
        let s =
            at(&x, p, g).ok_or_else(|| FreeError::NoConvergence("a pose maps to zero".into()))?;
        let r = s.geo.q - g - bias;
        let sd_noise = s.var.max((ROUND_OFF * g).powi(2)).sqrt();
        if sd_noise > 0.0 {
            chi2 += (r / sd_noise).powi(2);
        }
        results.push(PoseResult {
            name: p.name.clone(),
            direction: s.geo.n.into(),
            residual_ms2: r,
            residual_std_ms2: 1.0 / inv_sd,
        });
    }
    let dof = poses.len().saturating_sub(PARAMS);
    let nu = if tau > 0.0 { dof as f64 } else { f64::INFINITY };
    Ok(FreeFit {
        // The columns of Lᵀ: the rows of L.
        l: l_of(&x).transpose().into(),
        offsets: offsets_of(&x),
        cov,
        poses: results,
        rejected: Vec::new(),
        chi2,
        dof,
        tau_ms2: tau,
        tau2_measured: None,
        cov_per_tau2,
        scatter_design,
        nu,
        k: coverage_factor(nu),
        condition_number: f64::NAN,
        suggestion: None,
        notes: Vec::new(),
        residual,
    })
}
