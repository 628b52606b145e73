//! The measurement session: which condition runs, its streaming f32 fit, the fit reports
//! (periodic, and final at stop), and after x, y and z the quick-look calibration from the
//! exact Gram form (docs/method.md §2).

use super::sampler::StreamSample;
use crate::fit::{FitConfig, FitResult, Param, SineFit};
use crate::intrinsic::{self, ConditionFit};
use crate::packet::{CommandError, FitReport, Packet, QuickLook, RunState};
use crate::phase::PhaseStep;
use crate::time::TickRate;
use crate::Condition;

/// The running condition.
#[derive(Clone, Debug)]
struct Active {
    condition: Condition,
    rate_uhz: u32,
    fit: SineFit<f32>,
    first_seq: Option<u32>,
    last_seq: u32,
    since_report: u32,
}

impl Active {
    fn report(&self, r: &FitResult<f32>, is_final: bool) -> FitReport {
        report(
            r,
            self.condition,
            is_final,
            self.first_seq.unwrap_or(0),
            self.last_seq,
            self.rate_uhz,
            self.fit.config().step,
        )
    }
}

/// See the module documentation.
#[derive(Clone, Debug)]
pub struct Session {
    clock: TickRate,
    publish_every: u32,
    g_loc: f64,
    active: Option<Active>,
    /// The last condition run (reported in the status while idle).
    last_condition: Option<Condition>,
    /// Final fits of x, y, z.
    done: [Option<ConditionFit>; 3],
    quick_look: Option<QuickLook>,
}

/// A fit result as the protocol carries it.
pub fn report(
    r: &FitResult<f32>,
    condition: Condition,
    is_final: bool,
    first_seq: u32,
    last_seq: u32,
    rate_uhz: u32,
    step: PhaseStep,
) -> FitReport {
    let mut coef = [[0.0f64; 3]; 3];
    let mut se = [[0.0f32; 3]; 3];
    let mut rms = [0.0f32; 3];
    for (ch, ((c, s), m)) in coef
        .iter_mut()
        .zip(se.iter_mut())
        .zip(rms.iter_mut())
        .enumerate()
    {
        for (k, p) in [Param::A, Param::B, Param::C].into_iter().enumerate() {
            if let Some(v) = c.get_mut(k) {
                // hi + lo of two f32 is exact in f64.
                *v = r
                    .coef(ch, p)
                    .map_or(f64::NAN, |d| f64::from(d.hi) + f64::from(d.lo));
            }
            if let Some(v) = s.get_mut(k) {
                *v = r.se(ch, p).unwrap_or(f32::NAN);
            }
        }
        *m = r.channels.get(ch).map_or(f32::NAN, |f| f.rms_residual);
    }
    FitReport {
        condition,
        is_final,
        n: r.n,
        first_seq,
        last_seq,
        rate_uhz,
        step: step.0,
        coef,
        se,
        rms,
    }
}

impl Session {
    /// Idle, nothing fitted.
    pub fn new(clock: TickRate, publish_every: u32, g_loc: f64) -> Self {
        Session {
            clock,
            publish_every,
            g_loc,
            active: None,
            last_condition: None,
            done: [None; 3],
            quick_look: None,
        }
    }

    /// Idle, running, or complete (all three conditions fitted).
    pub fn state(&self) -> RunState {
        if self.active.is_some() {
            RunState::Running
        } else if self.quick_look.is_some() {
            RunState::Complete
        } else {
            RunState::Idle
        }
    }

    /// The running condition, else the last one run.
    pub fn condition(&self) -> Option<Condition> {
        self.active
            .as_ref()
            .map(|a| a.condition)
            .or(self.last_condition)
    }

    /// The quick-look, once x, y and z are done.
    pub fn quick_look(&self) -> Option<QuickLook> {
        self.quick_look
    }

    /// Start fitting `condition` at the nominal rate (refused while running).
    pub fn start(&mut self, condition: Condition, rate_uhz: u32) -> Result<(), CommandError> {
        if self.active.is_some() {
            return Err(CommandError::Busy);
        }
        let step = PhaseStep::from_micro_hz(u64::from(rate_uhz), self.clock)
            .filter(|_| rate_uhz > 0)
            .ok_or(CommandError::BadRate)?;
        self.active = Some(Active {
            condition,
            rate_uhz,
            fit: SineFit::new(FitConfig::sine(step, self.clock)),
            first_seq: None,
            last_seq: 0,
            since_report: 0,
        });
        self.last_condition = Some(condition);
        Ok(())
    }

    /// Feed a streamed sample to the running fit; a periodic report goes out every
    /// `publish_every` samples once the fit has a result. A sample the fit refuses (its
    /// time went backwards after a counter fault) is left out of the fit only: the
    /// report's `n` then falls short of the seq window.
    pub fn on_sample(&mut self, s: &StreamSample, out: &mut impl FnMut(Packet)) {
        let Some(a) = &mut self.active else {
            return;
        };
        if a.fit
            .update_sum(&s.aperture, s.sums.map(|v| v as f32))
            .is_err()
        {
            return;
        }
        a.first_seq.get_or_insert(s.seq);
        a.last_seq = s.seq;
        a.since_report += 1;
        if self.publish_every > 0 && a.since_report >= self.publish_every {
            a.since_report = 0;
            if let Ok(r) = a.fit.solve() {
                out(Packet::Fit(a.report(&r, false)));
            }
        }
    }

    /// Stop: the final fit report, and the quick-look once x, y and z are all done.
    /// Refused when idle, or when the condition's fit has no result (too few samples or
    /// periods): then nothing is recorded for the condition.
    pub fn stop(&mut self, out: &mut impl FnMut(Packet)) -> Result<(), CommandError> {
        let a = self.active.take().ok_or(CommandError::NotRunning)?;
        let r = a.fit.solve().map_err(|_| CommandError::FitFailed)?;
        out(Packet::Fit(a.report(&r, true)));
        if let Some(slot) = self.done.get_mut(a.condition.index()) {
            *slot = Some(ConditionFit::from_fit(&r));
        }
        if let [Some(x), Some(y), Some(z)] = self.done {
            if let Ok(i) = intrinsic::from_gram(&[x, y, z], self.g_loc, 0.0) {
                let u = |e: [intrinsic::Estimate; 3]| e.map(|e| e.std_unc as f32);
                let q = QuickLook {
                    sensitivity: i.sensitivity.map(|e| e.value),
                    sensitivity_u: u(i.sensitivity),
                    angle_deg: i.angle_deg.map(|e| e.value),
                    angle_u: u(i.angle_deg),
                    g_loc: self.g_loc,
                };
                self.quick_look = Some(q);
                out(Packet::QuickLook(q));
            }
        }
        Ok(())
    }

    /// Forget everything fitted; stop without a report.
    pub fn reset(&mut self) {
        self.active = None;
        self.last_condition = None;
        self.done = [None; 3];
        self.quick_look = None;
    }
}
