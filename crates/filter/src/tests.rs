//! Known-answer and property tests of the filters against dense textbook
//! formulas written out here.

use insuwb_msg::{FilterDiag, FilterKind, Header};
use nalgebra::{SMatrix, SVector};

use crate::model::{dense, h_matrix, Mat14, Mat4, ModelConfig, ModelForm, PaperModel, Vec14};
use crate::params::{FilterParams, FilterSetup, LimitMode, OutlierForm};
use crate::testutil::Rng;
use crate::{build, BuildError, ErrorFilter, Iakf, Kf, Shaf, Stf, UpdateError};

type V4 = SVector<f64, 4>;
type V2 = SVector<f64, 2>;

fn model(form: ModelForm) -> PaperModel {
    let mut c = ModelConfig {
        form,
        ..ModelConfig::default()
    };
    c.ar_accel_e.m = [-0.6, 0.1, -0.05];
    c.ar_accel_n.m = [-0.3, -0.2, 0.1];
    c.ar_gyro.m = [-0.5, 0.05, 0.0];
    c.ar_accel_e.noise_var = 1e-3;
    c.ar_accel_n.noise_var = 2e-3;
    c.ar_gyro.noise_var = 1e-5;
    c.q_pos_m2_per_s = 1e-3;
    c.q_vel_m2_per_s3 = 1e-2;
    c.q_theta_rad2_per_s = 1e-4;
    PaperModel::new(c).unwrap()
}

fn setup() -> FilterSetup {
    FilterSetup {
        p0_diag: [
            1.0, 2.0, 0.5, 0.7, 0.01, 1e-3, 1e-3, 1e-3, 2e-3, 2e-3, 2e-3, 1e-5, 1e-5, 1e-5,
        ],
        r0_diag: [0.01, 0.02, 0.3, 0.4],
    }
}

fn assert_close(a: &Mat14, b: &Mat14, tol: f64, what: &str) {
    let scale = b.amax().max(1e-300);
    let e = (a - b).amax() / scale;
    assert!(e < tol, "{what}: relative difference {e}");
}

fn assert_vclose(a: &Vec14, b: &Vec14, tol: f64, what: &str) {
    let scale = b.amax().max(1.0);
    let e = (a - b).amax() / scale;
    assert!(e < tol, "{what}: relative difference {e}\n{a}\n{b}");
}

fn accel(k: usize) -> (f64, f64) {
    let t = k as f64 * 0.01;
    (1.2 * (0.7 * t).sin(), -0.8 * (0.4 * t).cos())
}

/// A textbook KF written out with dense matrices and an explicit inverse.
struct Textbook {
    x: Vec14,
    p: Mat14,
    r: Mat4,
}

impl Textbook {
    fn predict(&mut self, m: &PaperModel, dt: f64, a_e: f64, a_n: f64) {
        let f = dense(&m.transition(dt, a_e, a_n));
        self.x = f * self.x;
        self.p = f * self.p * f.transpose() + m.process_noise(dt);
    }

    fn update4(&mut self, z: &V4, p_pred: &Mat14, r: &Mat4) {
        let h = h_matrix();
        let s = h * p_pred * h.transpose() + r;
        let k = p_pred * h.transpose() * s.try_inverse().unwrap();
        self.x += k * (z - h * self.x);
        let a = Mat14::identity() - k * h;
        self.p = a * p_pred * a.transpose() + k * r * k.transpose();
    }

    fn update2(&mut self, z: &V2) {
        let h = SMatrix::<f64, 2, 14>::identity();
        let r = self.r.fixed_view::<2, 2>(0, 0).into_owned();
        let s = h * self.p * h.transpose() + r;
        let k = self.p * h.transpose() * s.try_inverse().unwrap();
        self.x += k * (z - h * self.x);
        let a = Mat14::identity() - k * h;
        self.p = a * self.p * a.transpose() + k * r * k.transpose();
    }
}

#[test]
fn kf_equals_textbook_kf() {
    for form in [ModelForm::Paper, ModelForm::Physics] {
        let m = model(form);
        let s = setup();
        let mut kf = Kf::new(m.clone(), &s).unwrap();
        let mut tb = Textbook {
            x: Vec14::zeros(),
            p: s.p0(),
            r: s.r0(),
        };
        let mut rng = Rng::new(7);
        for k in 0..400 {
            let (a_e, a_n) = accel(k);
            kf.predict(0.01, a_e, a_n).unwrap();
            tb.predict(&m, 0.01, a_e, a_n);
            if k % 10 == 9 {
                if k % 30 == 29 {
                    let z = V2::new(rng.normal(), rng.normal()) * 0.3;
                    let rep = kf.update_pos(&z).unwrap();
                    assert_eq!(rep.dim, 2);
                    assert_eq!(rep.innovation[2], 0.0);
                    tb.update2(&z);
                } else {
                    let z = V4::from_fn(|_, _| rng.normal()) * 0.3;
                    kf.update(&z).unwrap();
                    let p = tb.p;
                    let r = tb.r;
                    tb.update4(&z, &p, &r);
                }
                assert_vclose(kf.state(), &tb.x, 1e-9, "x");
                assert_close(kf.covariance(), &tb.p, 1e-9, "P");
            }
        }
        assert_eq!(kf.updates(), 40);
        assert_eq!(kf.r(), &s.r0());
    }
}

#[test]
fn kf_one_cycle_by_hand() {
    let m = model(ModelForm::Physics);
    let s = setup();
    let p = s.p0_diag;
    let mut kf = Kf::new(m.clone(), &s).unwrap();
    let (t, a_e, a_n) = (0.01, 0.3, -0.2);
    kf.predict(t, a_e, a_n).unwrap();
    let c = m.config();
    let (fe, fnn) = (-a_n * t, a_e * t);
    let [m1, m2, m3] = c.ar_accel_e.m;
    let pp = kf.covariance();
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b.abs().max(1.0);
    assert!(close(
        pp[(0, 0)],
        p[0] + t * t * p[2] + c.q_pos_m2_per_s * t
    ));
    assert!(close(pp[(0, 2)], t * p[2]));
    assert!(close(pp[(1, 3)], t * p[3]));
    assert!(close(
        pp[(2, 2)],
        p[2] + fe * fe * p[4] + t * t * p[5] + c.q_vel_m2_per_s3 * t
    ));
    assert!(close(pp[(2, 3)], fe * fnn * p[4]));
    assert!(close(pp[(2, 4)], fe * p[4]));
    assert!(close(pp[(3, 4)], fnn * p[4]));
    assert!(close(pp[(2, 5)], t * m1 * p[5]));
    assert!(close(
        pp[(4, 4)],
        p[4] + t * t * p[11] + c.q_theta_rad2_per_s * t
    ));
    assert!(close(
        pp[(5, 5)],
        m1 * m1 * p[5] + m2 * m2 * p[6] + m3 * m3 * p[7] + c.ar_accel_e.noise_var
    ));
    assert!(close(pp[(5, 6)], -m1 * p[5]));
    assert!(close(pp[(6, 6)], p[5]));
    assert!(close(pp[(7, 7)], p[6]));
    assert_eq!(pp[(0, 1)], 0.0);

    // An update right after a reset to a diagonal P: scalar Kalman gains.
    kf.reset(&s.p0()).unwrap();
    let z = V4::new(0.5, -0.25, 0.1, 0.2);
    let rep = kf.update(&z).unwrap();
    let r = s.r0_diag;
    for i in 0..4 {
        let k = p[i] / (p[i] + r[i]);
        assert!(close(kf.state()[i], k * z[i]), "x[{i}]");
        assert!(close(kf.covariance()[(i, i)], p[i] * r[i] / (p[i] + r[i])));
        assert!(close(rep.innovation_var[i], p[i] + r[i]));
    }
    let nis: f64 = (0..4).map(|i| z[i] * z[i] / (p[i] + r[i])).sum();
    assert!(close(rep.nis, nis));
    assert_eq!(kf.state()[4], 0.0);
    assert_eq!(kf.covariance()[(4, 4)], p[4]);
}

#[test]
fn multi_step_predict_equals_repeated_steps() {
    let m = model(ModelForm::Physics);
    let s = setup();
    let mut a = Kf::new(m.clone(), &s).unwrap();
    let mut b = Kf::new(m, &s).unwrap();
    a.update(&V4::new(0.3, 0.2, 0.1, 0.0)).unwrap();
    b.update(&V4::new(0.3, 0.2, 0.1, 0.0)).unwrap();
    a.predict(0.1, 0.5, -0.4).unwrap();
    for _ in 0..10 {
        b.predict(0.1 / 10.0, 0.5, -0.4).unwrap();
    }
    assert_vclose(a.state(), b.state(), 1e-15, "x");
    assert_close(a.covariance(), b.covariance(), 1e-15, "P");
}

fn shaf_params() -> FilterParams {
    FilterParams {
        b: 0.9,
        warmup_updates: 0,
        ..FilterParams::default()
    }
}

#[test]
fn shaf_r_estimate_by_hand() {
    let s = setup();
    let params = shaf_params();
    let mut f = Shaf::new(model(ModelForm::Paper), &params, &s).unwrap();
    let p = s.p0_diag;
    let r0 = s.r0_diag;
    let z1 = V4::new(0.3, -0.2, 0.5, 0.4);
    let rep = f.update(&z1).unwrap();
    // k = 1 (erratum 8): d = (1 - b) / (1 - b^2); K_0 = 0, P_0 (erratum 7).
    let d1 = 0.1 / (1.0 - 0.81);
    let mut r1 = [0.0; 4];
    for i in 0..4 {
        r1[i] = (1.0 - d1) * r0[i] + d1 * (z1[i] * z1[i] + p[i]);
        assert!((f.r()[(i, i)] - r1[i]).abs() < 1e-15, "R1[{i}]");
        assert!((rep.r_diag[i] - r1[i]).abs() < 1e-15);
        // Gain with R_1 (erratum 9).
        let k = p[i] / (p[i] + r1[i]);
        assert!((f.state()[i] - k * z1[i]).abs() < 1e-15);
    }
    assert_eq!(f.r()[(0, 1)], 0.0, "diagonal R by default");
    // k = 2: residual with K_1 and P_1.
    let x1 = *f.state();
    let z2 = V4::new(-0.1, 0.3, 0.2, -0.6);
    f.update(&z2).unwrap();
    let d2 = 0.1 / (1.0 - 0.9_f64.powi(3));
    for i in 0..4 {
        let k1 = p[i] / (p[i] + r1[i]);
        let p1 = p[i] * r1[i] / (p[i] + r1[i]);
        let v = z2[i] - x1[i];
        let e = (1.0 - k1) * v;
        let r2 = (1.0 - d2) * r1[i] + d2 * (e * e + p1);
        assert!((f.r()[(i, i)] - r2).abs() < 1e-14, "R2[{i}]");
    }
}

#[test]
fn shaf_warmup_and_clamp() {
    let s = setup();
    let params = FilterParams {
        warmup_updates: 3,
        ..shaf_params()
    };
    let mut f = Shaf::new(model(ModelForm::Paper), &params, &s).unwrap();
    for _ in 0..3 {
        f.update(&V4::new(0.3, 0.3, 0.3, 0.3)).unwrap();
        assert_eq!(f.r(), &s.r0(), "held during warm-up");
    }
    f.update(&V4::new(0.3, 0.3, 0.3, 0.3)).unwrap();
    assert_ne!(f.r(), &s.r0());
    // A 100 m innovation drives R to the clamp r_max_factor * R_0.
    f.update(&V4::new(100.0, 0.0, 0.0, 0.0)).unwrap();
    assert_eq!(f.r()[(0, 0)], params.r_max_factor * s.r0_diag[0]);
    // Zero innovations for long drive R to its floor r_min_factor * R_0.
    for _ in 0..500 {
        f.take_correction();
        f.update(&V4::zeros()).unwrap();
    }
    assert_eq!(f.r()[(3, 3)], params.r_min_factor * s.r0_diag[3]);
    // The full form keeps off-diagonals.
    let full = FilterParams {
        adapt_full_r: true,
        ..shaf_params()
    };
    let mut f = Shaf::new(model(ModelForm::Paper), &full, &s).unwrap();
    f.update(&V4::new(0.3, 0.3, 0.3, 0.3)).unwrap();
    assert!(f.r()[(0, 1)] > 0.0);
    assert!(f.r().cholesky().is_some());
}

/// Clean innovations plus a few outliers and steps, for the equivalence tests.
fn measurement(k: usize, rng: &mut Rng) -> V4 {
    let mut z = V4::new(
        0.1 * rng.normal(),
        0.1 * rng.normal(),
        0.5 * rng.normal(),
        0.5 * rng.normal(),
    );
    if k % 17 == 5 {
        z[0] += 1.0;
    }
    if k % 23 == 11 {
        z[3] -= 4.0;
    }
    z
}

#[test]
fn iakf_without_outliers_and_fading_equals_shaf() {
    for full in [false, true] {
        for limit_mode in [LimitMode::ScaleInnovation, LimitMode::InflateR] {
            let params = FilterParams {
                outlier_form: OutlierForm::Off,
                divergence_fading: false,
                adapt_full_r: full,
                limit_mode,
                warmup_updates: 5,
                ..FilterParams::default()
            };
            let m = model(ModelForm::Physics);
            let s = setup();
            let mut a = Shaf::new(m.clone(), &params, &s).unwrap();
            let mut b = Iakf::new(m, &params, &s).unwrap();
            let mut rng = Rng::new(11);
            for k in 0..2000 {
                let (a_e, a_n) = accel(k);
                a.predict(0.01, a_e, a_n).unwrap();
                b.predict(0.01, a_e, a_n).unwrap();
                if k % 10 == 9 {
                    let z = measurement(k / 10, &mut rng);
                    let (ra, rb) = if k % 50 == 49 {
                        let zp = z.fixed_rows::<2>(0).into_owned();
                        (a.update_pos(&zp).unwrap(), b.update_pos(&zp).unwrap())
                    } else {
                        (a.update(&z).unwrap(), b.update(&z).unwrap())
                    };
                    assert_eq!(ra, rb);
                    if k % 20 == 19 {
                        assert_eq!(a.take_correction(), b.take_correction());
                    }
                }
                assert_eq!(a.state(), b.state());
                assert_eq!(a.covariance(), b.covariance());
                assert_eq!(a.r(), b.r());
            }
        }
    }
}

fn iakf_params() -> FilterParams {
    FilterParams {
        divergence_fading: false,
        ..FilterParams::default()
    }
}

/// Two IAKFs (weighting on and off) brought to the same state by clean updates.
fn converged_pair(on: &FilterParams) -> (Iakf, Iakf) {
    let m = model(ModelForm::Physics);
    let s = setup();
    let off = FilterParams {
        outlier_form: OutlierForm::Off,
        ..on.clone()
    };
    let mut a = Iakf::new(m.clone(), on, &s).unwrap();
    let mut b = Iakf::new(m, &off, &s).unwrap();
    for k in 0..300 {
        let (a_e, a_n) = accel(k);
        a.predict(0.01, a_e, a_n).unwrap();
        b.predict(0.01, a_e, a_n).unwrap();
        if k % 10 == 9 {
            let z = V4::new(0.01, -0.01, 0.02, 0.0);
            let ra = a.update(&z).unwrap();
            b.update(&z).unwrap();
            assert!(!ra.outlier);
            a.take_correction();
            b.take_correction();
        }
    }
    assert_eq!(a.state(), b.state());
    assert_eq!(a.covariance(), b.covariance());
    (a, b)
}

#[test]
fn outlier_spike_is_clipped_at_kappa_sigma() {
    let params = iakf_params();
    let (mut a, mut b) = converged_pair(&params);
    a.predict(0.01, 0.0, 0.0).unwrap();
    b.predict(0.01, 0.0, 0.0).unwrap();
    let x_pred = *a.state();
    let z = V4::new(1.0 + 0.01, -0.01, 0.02, 0.0); // 1 m spike on east position
    let rep = a.update(&z).unwrap();
    assert!(rep.outlier && !rep.divergence);
    let s00 = rep.innovation_var[0];
    assert!(
        (s00 - (b.covariance()[(0, 0)] + b.r()[(0, 0)])).abs() < 1e-15,
        "S_00 = P_00 + R_00"
    );
    let clipped = rep.lambda[0] * rep.innovation[0].abs();
    let bound = params.kappa * s00.sqrt();
    assert!(rep.innovation[0] > 10.0 * s00.sqrt(), "a real spike");
    assert!(clipped <= bound * (1.0 + 1e-12), "{clipped} > {bound}");
    assert!(
        clipped >= bound * (1.0 - 1e-12),
        "clipped exactly at kappa sigma"
    );
    assert_eq!(&rep.lambda[1..], &[1.0, 1.0, 1.0]);
    // Same result as feeding the clipped innovation to the unweighted filter.
    let mut zc = z;
    zc[0] = x_pred[0] + rep.lambda[0] * rep.innovation[0];
    let rb = b.update(&zc).unwrap();
    assert!(!rb.outlier);
    assert_vclose(a.state(), b.state(), 1e-12, "x");
    assert_close(a.covariance(), b.covariance(), 1e-12, "P");
    let dr = (a.r() - b.r()).amax() / b.r().amax();
    assert!(dr < 1e-12, "R estimated from the weighted innovation");
}

#[test]
fn outlier_inflate_r_mode() {
    let params = FilterParams {
        limit_mode: LimitMode::InflateR,
        ..iakf_params()
    };
    let (mut a, mut b) = converged_pair(&params);
    let z = V4::new(0.0, 0.0, 0.0, 8.0); // velocity north spike
    let rep = a.update(&z).unwrap();
    let rb = b.update(&z).unwrap();
    assert!(rep.outlier);
    let l = rep.lambda[3];
    assert!(l < 1.0 && l > 0.0);
    assert!(
        (l * 8.0 - params.kappa * rep.innovation_var[3].sqrt()).abs() < 1e-12,
        "lambda = kappa sigma / |v|"
    );
    // R_33 inflated by 1/lambda^2 in the gain; the stored R is not inflated.
    assert!((rep.r_diag[3] - a.r()[(3, 3)] / (l * l)).abs() < 1e-12 * rep.r_diag[3]);
    assert!(a.state()[3].abs() < b.state()[3].abs() * 0.5);
    assert!(rb.r_diag[3] < rep.r_diag[3]);
}

#[test]
fn z_form_tests_the_measurement_not_the_innovation() {
    let s = setup();
    for (form, flagged) in [(OutlierForm::Innovation, false), (OutlierForm::ZForm, true)] {
        let params = FilterParams {
            outlier_form: form,
            ..iakf_params()
        };
        let mut f = Iakf::new(model(ModelForm::Paper), &params, &s).unwrap();
        // Open loop: drive the position estimate to about 2 m.
        f.update(&V4::new(2.0, 0.0, 0.0, 0.0)).unwrap();
        let x0 = f.state()[0];
        assert!((x0 - 2.0).abs() < 0.05);
        let s00 = f.covariance()[(0, 0)] + f.r()[(0, 0)];
        let z = V4::new(x0 + 2.0 * s00.sqrt(), 0.0, 0.0, 0.0); // a 2-sigma innovation
        let rep = f.update(&z).unwrap();
        assert_eq!(rep.outlier, flagged, "{form:?}");
        if flagged {
            // lambda = sqrt((D + eps) / G), G = Z^2, D = S + (H X-)^2, eps = 8 S.
            let want = ((s00 + x0 * x0 + 8.0 * s00) / (z[0] * z[0])).sqrt();
            assert!(
                (rep.lambda[0] - want).abs() < 1e-14,
                "{} vs {want}",
                rep.lambda[0]
            );
        }
    }
}

/// `F`, `Q` of one step and `F P F^T` for the fading known answers.
fn one_step(m: &PaperModel, p: &Mat14, dt: f64, a_e: f64, a_n: f64) -> (Mat14, Mat14) {
    let f = dense(&m.transition(dt, a_e, a_n));
    (f * p * f.transpose(), m.process_noise(dt))
}

fn faded(fpf: &Mat14, q: &Mat14, f: f64, n: usize) -> Mat14 {
    let mut p = fpf + q;
    for i in 0..n {
        for j in 0..n {
            p[(i, j)] = f * fpf[(i, j)] + q[(i, j)];
        }
    }
    p
}

#[test]
fn stf_fading_by_hand() {
    let m = model(ModelForm::Physics);
    let s = setup();
    let params = FilterParams {
        stf_rho: 0.8,
        stf_beta: 1.5,
        ..FilterParams::default()
    };
    let mut stf = Stf::new(m.clone(), &params, &s).unwrap();
    let r = s.r0();
    // Two IMU steps, then an update: Phi P0 Phi^T and Q_acc over the interval.
    let (fpf1, q1) = one_step(&m, &s.p0(), 0.01, 0.3, 0.1);
    let (fpf2, q2) = one_step(&m, &(fpf1 + q1), 0.01, 0.3, 0.1);
    let (qq, _) = one_step(&m, &q1, 0.01, 0.3, 0.1);
    let q_acc = qq + q2; // F Q1 F^T + Q2
    let phi_p_phi = fpf2 + q2 - q_acc; // P- - Q_acc = F F P0 F^T F^T
    stf.predict(0.01, 0.3, 0.1).unwrap();
    stf.predict(0.01, 0.3, 0.1).unwrap();
    let z = V4::new(2.0, 2.0, 1.0, 1.0);
    let rep = stf.update(&z).unwrap();
    let tr = |m: &Mat14| (0..4).map(|i| m[(i, i)]).sum::<f64>();
    let tr_n = z.dot(&z) - 1.5 * r.trace() - tr(&q_acc);
    let f1 = tr_n / tr(&phi_p_phi);
    assert!(f1 > 1.0 && f1 < params.fading_cap, "f1 = {f1}");
    assert!(
        (rep.fading - f1).abs() < 1e-12 * f1,
        "{} vs {f1}",
        rep.fading
    );
    let mut tb = Textbook {
        x: Vec14::zeros(),
        p: Mat14::zeros(),
        r,
    };
    let p_pred = faded(&phi_p_phi, &q_acc, f1, 4);
    tb.update4(&z, &p_pred, &r);
    assert_vclose(stf.state(), &tb.x, 1e-10, "x after fading");
    assert_close(stf.covariance(), &tb.p, 1e-10, "P after fading");

    // Second update: V_2 = (rho V_1 + v v^T) / (1 + rho), P_{k-1} = P_1.
    let p1 = *stf.covariance();
    let x1 = *stf.state();
    let (fpf, q) = one_step(&m, &p1, 0.01, 0.0, 0.0);
    stf.predict(0.01, 0.0, 0.0).unwrap();
    let f = dense(&m.transition(0.01, 0.0, 0.0));
    let x_pred = f * x1;
    let z2 = h_matrix() * x_pred + V4::new(0.05, -0.1, 0.2, 0.1);
    let v1 = z; // x- was 0 at the first update
    let v2 = z2 - h_matrix() * x_pred;
    let vk = (v1 * v1.transpose() * 0.8 + v2 * v2.transpose()) / 1.8;
    let tr_n = vk.trace() - 1.5 * r.trace() - tr(&q);
    let want = tr_n / tr(&fpf);
    assert!(want > 1.0 && want < params.fading_cap, "f2 = {want}");
    let rep = stf.update(&z2).unwrap();
    assert!(
        (rep.fading - want).abs() < 1e-12 * want,
        "{} vs {want}",
        rep.fading
    );
}

#[test]
fn stf_fading_is_at_least_one_and_capped() {
    let m = model(ModelForm::Physics);
    let s = setup();
    let params = FilterParams::default();
    let mut stf = Stf::new(m, &params, &s).unwrap();
    stf.predict(0.01, 0.0, 0.0).unwrap();
    let rep = stf.update(&V4::zeros()).unwrap();
    assert_eq!(rep.fading, 1.0);
    stf.predict(0.01, 0.0, 0.0).unwrap();
    let rep = stf.update(&V4::new(50.0, 50.0, 50.0, 50.0)).unwrap();
    assert_eq!(rep.fading, params.fading_cap);
    let mut rng = Rng::new(3);
    let mut above = 0;
    for k in 0..3000 {
        let (a_e, a_n) = accel(k);
        stf.predict(0.01, a_e, a_n).unwrap();
        if k % 10 == 9 {
            let rep = stf.update(&measurement(k / 10, &mut rng)).unwrap();
            assert!(rep.fading >= 1.0 && rep.fading <= params.fading_cap);
            above += usize::from(rep.fading > 1.0);
            stf.take_correction();
        }
    }
    assert!(above > 0);
}

#[test]
fn iakf_divergence_branch_fades_and_freezes_r() {
    let m = model(ModelForm::Physics);
    let s = setup();
    let params = FilterParams {
        warmup_updates: 0,
        ..FilterParams::default()
    };
    let mut f = Iakf::new(m.clone(), &params, &s).unwrap();
    let (fpf, q) = one_step(&m, &s.p0(), 0.01, 0.2, -0.1);
    f.predict(0.01, 0.2, -0.1).unwrap();
    let r = s.r0();
    // Every component at 2.5 sigma: no outlier (kappa = 3), but
    // v^T v = 6.25 tr(S) > gamma tr(S) with gamma = 4.
    let s_diag: Vec<f64> = (0..4)
        .map(|i| fpf[(i, i)] + q[(i, i)] + r[(i, i)])
        .collect();
    let z = V4::from_fn(|i, _| 2.5 * s_diag[i].sqrt() * if i % 2 == 0 { 1.0 } else { -1.0 });
    let rep = f.update(&z).unwrap();
    assert!(rep.divergence && !rep.outlier);
    let tr = |m: &Mat14| (0..4).map(|i| m[(i, i)]).sum::<f64>();
    let want = (z.dot(&z) - tr(&q) - r.trace()) / tr(&fpf);
    assert!(want > 1.0 && want < params.fading_cap);
    assert!((rep.fading - want).abs() < 1e-12 * want);
    assert_eq!(f.r(), &r, "R frozen on the fading branch");
    let mut tb = Textbook {
        x: Vec14::zeros(),
        p: Mat14::zeros(),
        r,
    };
    tb.update4(&z, &faded(&fpf, &q, want, 4), &r);
    assert_vclose(f.state(), &tb.x, 1e-10, "x");
    assert_close(f.covariance(), &tb.p, 1e-10, "P");

    // Same epoch with one component beyond kappa sigma: outlier, no divergence.
    let mut g = Iakf::new(m.clone(), &params, &s).unwrap();
    g.predict(0.01, 0.2, -0.1).unwrap();
    let mut z2 = z;
    z2[0] *= 2.0;
    let rep = g.update(&z2).unwrap();
    assert!(rep.outlier && !rep.divergence);
    assert_eq!(rep.fading, 1.0);
    assert_ne!(g.r(), &r, "Sage-Husa branch adapts R");

    // Small innovations: neither.
    let mut g = Iakf::new(m, &params, &s).unwrap();
    g.predict(0.01, 0.2, -0.1).unwrap();
    let rep = g.update(&(z * 0.5)).unwrap();
    assert!(!rep.outlier && !rep.divergence);
}

/// Data generated from the filter's own model (`F`, `Q`, `H`, `R`, `P_0`).
struct Truth {
    x: Vec14,
}

impl Truth {
    fn new(s: &FilterSetup, rng: &mut Rng) -> Self {
        Self {
            x: Vec14::from_fn(|i, _| s.p0_diag[i].sqrt() * rng.normal()),
        }
    }

    fn step(&mut self, m: &PaperModel, dt: f64, a_e: f64, a_n: f64, rng: &mut Rng) {
        let q = m.process_noise_diag(dt);
        self.x = dense(&m.transition(dt, a_e, a_n)) * self.x
            + Vec14::from_fn(|i, _| q[i].sqrt() * rng.normal());
    }

    fn measure(&self, s: &FilterSetup, rng: &mut Rng) -> V4 {
        V4::from_fn(|i, _| self.x[i] + s.r0_diag[i].sqrt() * rng.normal())
    }
}

#[test]
fn long_clean_run_stays_finite_spd_and_kf_is_consistent() {
    let s = setup();
    let params = FilterParams::default();
    for form in [ModelForm::Paper, ModelForm::Physics] {
        for kind in [
            FilterKind::Kf,
            FilterKind::Shaf,
            FilterKind::Stf,
            FilterKind::Iakf,
        ] {
            let m = model(form);
            let mut f = build(kind, m.clone(), &params, &s).unwrap();
            let mut rng = Rng::new(1234);
            let mut truth = Truth::new(&s, &mut rng);
            let (mut nis_sum, mut n) = (0.0, 0usize);
            let (mut err2, mut var) = (0.0, 0.0);
            for k in 0..30_000 {
                let (a_e, a_n) = accel(k);
                truth.step(&m, 0.01, a_e, a_n, &mut rng);
                f.predict(0.01, a_e, a_n).unwrap();
                if k % 10 == 9 {
                    let z = truth.measure(&s, &mut rng);
                    let rep = f.update(&z).unwrap();
                    let p = f.covariance();
                    assert!(f.state().iter().all(|v| v.is_finite()), "{kind:?}");
                    assert_eq!(p, &p.transpose(), "{kind:?} P symmetric");
                    assert!(p.cholesky().is_some(), "{kind:?} {form:?} P SPD at {k}");
                    if k > 1000 {
                        nis_sum += rep.nis;
                        n += 1;
                        let e = f.state()[0] - truth.x[0];
                        err2 += e * e;
                        var += p[(0, 0)];
                    }
                }
            }
            if kind == FilterKind::Kf {
                let mean_nis = nis_sum / n as f64;
                assert!(
                    (3.7..4.3).contains(&mean_nis),
                    "{form:?} mean NIS {mean_nis}"
                );
                let ratio = err2 / var;
                assert!((0.8..1.2).contains(&ratio), "{form:?} NEES ratio {ratio}");
            }
        }
    }
}

#[test]
fn refused_inputs_leave_the_filter_unchanged() {
    let s = setup();
    let m = model(ModelForm::Physics);
    for kind in [
        FilterKind::Kf,
        FilterKind::Shaf,
        FilterKind::Stf,
        FilterKind::Iakf,
    ] {
        let mut f = build(kind, m.clone(), &FilterParams::default(), &s).unwrap();
        f.predict(0.01, 0.1, 0.1).unwrap();
        let (x, p, r) = (*f.state(), *f.covariance(), *f.r());
        let e = f.update(&V4::new(0.0, f64::NAN, 0.0, 0.0)).unwrap_err();
        assert!(matches!(
            e,
            UpdateError::NonFiniteMeasurement { index: 1, .. }
        ));
        assert!(e.to_string().contains("component 1"));
        assert!(f.predict(0.01, f64::INFINITY, 0.0).is_err());
        assert!(f.predict(0.001, 0.0, 0.0).is_err());
        assert!(f.predict(0.01, 1e200, 1e200).is_err(), "overflow refused");
        assert_eq!((f.state(), f.covariance(), f.r()), (&x, &p, &r));

        // An indefinite P0 makes S indefinite: the update is refused.
        let mut bad = s.p0();
        bad[(0, 1)] = 5.0;
        bad[(1, 0)] = 5.0;
        f.reset(&bad).unwrap();
        let before = (*f.state(), *f.covariance());
        let e = f.update(&V4::new(0.1, 0.1, 0.0, 0.0)).unwrap_err();
        assert!(matches!(e, UpdateError::NotPositiveDefinite { .. }), "{e}");
        assert_eq!((*f.state(), *f.covariance()), before);
        assert_eq!(f.updates(), 0);

        let mut nan = s.p0();
        nan[(3, 3)] = f64::NAN;
        assert!(f.reset(&nan).is_err());
        let mut asym = s.p0();
        asym[(0, 5)] = 0.1;
        assert!(f.reset(&asym).is_err());
        let mut neg = s.p0();
        neg[(2, 2)] = -1.0;
        assert!(f.reset(&neg).is_err());
        assert_eq!(f.covariance(), &before.1);
    }
}

#[test]
fn take_correction_and_reset() {
    let s = setup();
    let mut f = build(
        FilterKind::Iakf,
        model(ModelForm::Physics),
        &shaf_params(),
        &s,
    )
    .unwrap();
    f.update(&V4::new(0.5, 0.5, 0.5, 0.5)).unwrap();
    let x = *f.state();
    let p = *f.covariance();
    assert!(x[0] > 0.0);
    assert_eq!(f.take_correction(), x);
    assert_eq!(f.state(), &Vec14::zeros());
    assert_eq!(f.covariance(), &p);
    assert_ne!(f.r(), &s.r0());
    f.reset(&s.p0()).unwrap();
    assert_eq!(f.covariance(), &s.p0());
    assert_eq!(f.r(), &s.r0());
    assert_eq!(f.updates(), 0);
}

/// A restarted filter resumes its adaptive `R`: the IAKF's (and the
/// SHAF's) Sage-Husa count and `R` go into `adaptive_state` and come back
/// after a reset, out of warm-up; a state that does not fit (length, `R`
/// outside its clamp, asymmetric, not finite) is refused and changes
/// nothing; the KF and the STF, whose `R` is fixed, keep none.
#[test]
fn adaptive_r_survives_a_restart() {
    let s = setup();
    let params = FilterParams {
        warmup_updates: 5,
        ..shaf_params()
    };
    for kind in [FilterKind::Iakf, FilterKind::Shaf] {
        let mut f = build(kind, model(ModelForm::Physics), &params, &s).unwrap();
        for k in 0..40 {
            f.predict(0.1, 0.0, 0.0).unwrap();
            f.update(&V4::new(0.4, -0.3, 0.8, 0.6 + 0.01 * k as f64))
                .unwrap();
            f.take_correction();
        }
        assert!(f.r()[(0, 0)] > 2.0 * s.r0_diag[0], "{kind:?}: R grew");
        let mut state = Vec::new();
        f.adaptive_state(&mut state);
        assert_eq!(state.len(), 17);
        assert_eq!(state[0], 40.0);

        let mut g = build(kind, model(ModelForm::Physics), &params, &s).unwrap();
        g.reset(f.covariance()).unwrap();
        let r0 = *g.r();
        for bad in [
            &state[1..],
            &[[41.0].as_slice(), &[1e6; 16]].concat()[..],
            &[f64::NAN; 17][..],
        ] {
            assert!(!g.restore_adaptive_state(bad), "{kind:?}: {bad:?}");
            assert_eq!(g.r(), &r0);
        }
        let mut asym = state.clone();
        asym[2] += 1e-3;
        assert!(!g.restore_adaptive_state(&asym));
        assert!(g.restore_adaptive_state(&state), "{kind:?}");
        assert_eq!(g.r(), f.r());
        // Out of warm-up: the next update moves R at once, as it moves the
        // original's.
        let z = V4::new(0.5, 0.5, 0.5, 0.5);
        f.predict(0.1, 0.0, 0.0).unwrap();
        g.predict(0.1, 0.0, 0.0).unwrap();
        f.update(&z).unwrap();
        g.update(&z).unwrap();
        assert_ne!(g.r(), f.r(), "H K of the original is not kept");
        for i in 0..4 {
            let (a, b) = (f.r()[(i, i)], g.r()[(i, i)]);
            assert!((a - b).abs() < 0.2 * a, "{kind:?} R[{i}]: {a} against {b}");
        }
    }
    for kind in [FilterKind::Kf, FilterKind::Stf] {
        let mut f = build(kind, model(ModelForm::Physics), &params, &s).unwrap();
        let mut state = vec![1.0];
        f.adaptive_state(&mut state);
        assert!(state.is_empty(), "{kind:?}");
        assert!(!f.restore_adaptive_state(&[0.0; 17]));
    }
}

#[test]
fn build_maps_kinds_and_refuses_bad_input() {
    let s = setup();
    let m = model(ModelForm::Paper);
    for kind in [
        FilterKind::Kf,
        FilterKind::Shaf,
        FilterKind::Stf,
        FilterKind::Iakf,
    ] {
        let f = build(kind, m.clone(), &FilterParams::default(), &s).unwrap();
        assert_eq!(f.kind(), kind);
        assert_eq!(f.model(), &m);
    }
    let e = build(
        FilterKind::IakfTdoa,
        m.clone(),
        &FilterParams::default(),
        &s,
    )
    .unwrap_err();
    assert_eq!(
        e,
        BuildError::UnsupportedKind {
            kind: FilterKind::IakfTdoa
        }
    );
    let bad = FilterParams {
        gamma: 0.5,
        ..FilterParams::default()
    };
    let e = build(FilterKind::Kf, m.clone(), &bad, &s).unwrap_err();
    assert_eq!(e.to_string(), "filter.gamma must be > 1, got 0.5");
    let mut bad = s.clone();
    bad.r0_diag[0] = -1.0;
    assert!(Kf::new(m, &bad).is_err());
}

#[test]
fn report_to_diag() {
    let rep = crate::UpdateReport {
        dim: 4,
        innovation: [1.0, 2.0, 3.0, 4.0],
        innovation_var: [0.1, 0.2, 0.3, 0.4],
        lambda: [1.0, 0.5, 1.0, 1.0],
        r_diag: [0.01, 0.02, 0.03, 0.04],
        nis: 12.0,
        fading: 1.5,
        divergence: true,
        outlier: true,
    };
    let d = rep.to_diag(Header::new(9, 100), FilterKind::Iakf);
    assert_eq!(d.header.seq, 9);
    assert_eq!(
        d.header.flags,
        FilterDiag::FLAG_DIVERGENCE | FilterDiag::FLAG_OUTLIER
    );
    assert_eq!(d.innovation[..4], rep.innovation);
    assert_eq!(d.innovation[4..], [0.0; 4]);
    assert_eq!(d.lambda[1], 0.5);
    assert_eq!((d.dim, d.filter_kind), (4, 4));
    assert_eq!((d.nis, d.fading), (12.0, 1.5));
}
