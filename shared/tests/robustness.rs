//! Bad input gets a typed error, never a panic or NaN: arbitrary values (NaN, ±∞, huge,
//! subnormal) at arbitrary, possibly backwards, times.
use proptest::prelude::*;
use rotacal_shared::{FitConfig, Model, PhaseStep, SineFit, TickRate, Ticks};

fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>(),
        -40_000.0f32..40_000.0,
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::MIN_POSITIVE / 2.0),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn never_panics_never_nan(
        samples in prop::collection::vec((any::<u64>(), prop::array::uniform3(any_f32())), 0..80),
        step in any::<u64>(),
        drift in any::<bool>(),
        rate in any::<bool>(),
        min_milli in 0u32..3000,
    ) {
        let model = Model { offset_drift: drift, rate_error: rate };
        let cfg = FitConfig { model, min_milli_periods: min_milli, ..FitConfig::sine(PhaseStep(step), TickRate::RTC_32K) };
        let mut fit = SineFit::<f32>::new(cfg);
        let mut sorted = samples.clone();
        sorted.sort_by_key(|s| s.0);
        for (t, y) in samples.iter().chain(sorted.iter()) {
            let before = fit.len();
            if fit.update(Ticks(*t), *y).is_err() {
                prop_assert_eq!(fit.len(), before, "a refused sample changed the fit");
            }
        }
        if let Ok(r) = fit.solve() {
            for c in &r.channels {
                prop_assert!(c.coef.iter().all(|v| v.hi.is_finite() && v.lo.is_finite()));
                prop_assert!(c.se.iter().all(|v| v.is_finite() && *v >= 0.0));
                prop_assert!(c.sigma.is_finite() && c.rms_residual.is_finite());
            }
        }
    }
}
