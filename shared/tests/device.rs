//! The firmware's logic on the host: a simulated three-condition session through
//! `Device`, its packets decoded and checked against f64 fits of the same samples, and its
//! command handling, backfill, batching and clock extension.
// A test reports failure by panicking; the crate itself (src/) allows none of these.
#![allow(clippy::unwrap_used, clippy::indexing_slicing, clippy::panic)]
// Small fixed arrays read more plainly with indices.
#![allow(clippy::needless_range_loop)]

use rotacal_shared::device::simulated::SessionSpec;
use rotacal_shared::device::{Config, Device};
use rotacal_shared::packet::*;
use rotacal_shared::synth::crosscheck;
use rotacal_shared::{Aperture, Condition, FitConfig, Param, PhaseStep, SineFit, TickRate};

const RING: usize = rotacal_shared::device::RING;

fn run_paper() -> (Vec<Packet>, Device<RING>) {
    run_paper_at(rotacal_shared::device::route::MAX_MTU)
}

/// The paper session over a link of ATT MTU `mtu`.
fn run_paper_at(mtu: u16) -> (Vec<Packet>, Device<RING>) {
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let mut packets = Vec::new();
    dev.set_link_mtu(mtu, &mut |p| packets.push(p));
    SessionSpec::PAPER.run(&mut dev, &mut |p| {
        // Every packet crosses the wire: encode, decode, compare bytes.
        let mut buf = [0u8; MAX_PACKET];
        let n = p.encode(&mut buf).unwrap();
        let back = Packet::decode(&buf[..n]).unwrap();
        let mut again = [0u8; MAX_PACKET];
        assert_eq!(back.encode(&mut again).unwrap(), n);
        assert_eq!(buf[..n], again[..n]);
        packets.push(back);
    });
    (packets, dev)
}

/// (seq, conversion instants, sums, condition) of every live sample.
fn samples(packets: &[Packet]) -> Vec<(u32, Aperture, [i32; 3], Condition)> {
    let mut out = Vec::new();
    for p in packets {
        if let Packet::Averages(b) = p {
            assert!(!b.replay);
            for (seq, ap, s) in b.iter() {
                out.push((seq, ap, s.sums, b.condition));
            }
        }
    }
    out
}

/// Streamed samples of the paper session: 4199 per condition (the slot open at stop is
/// dropped), 16 Hz for 262.5 s.
const STREAMED: u32 = 3 * 4199;

#[test]
fn paper_session_streams_every_conversion_once_in_order() {
    let (packets, dev) = run_paper();
    let s = samples(&packets);
    assert_eq!(s.len(), STREAMED as usize);
    for (i, w) in s.windows(2).enumerate() {
        assert_eq!(w[1].0, w[0].0 + 1, "seq contiguous at {i}");
        assert!(w[1].1.first() > w[0].1.last(), "time increases at {i}");
        if w[0].3 == w[1].3 {
            // Slots of 62 500 µs on one grid: the first conversions of neighbours are
            // within one sensor period (9615 µs) of 62 500 µs apart.
            let dt = w[1].1.first().0 - w[0].1.first().0;
            assert!(
                (62_500 - 9_616..=62_500 + 9_616).contains(&dt),
                "spacing {dt} at {i}"
            );
        }
    }
    // Every conversion the sensor made is in exactly one sample, with its own tick and
    // counts, but for those of the slot still open at each stop (at most 7).
    let spec = SessionSpec::PAPER;
    for (k, cond) in Condition::ALL.into_iter().enumerate() {
        let base = spec
            .counter_start
            .wrapping_add(spec.condition_spacing * k as u64);
        let conv: Vec<(u64, [i16; 3])> = spec
            .sensor(cond)
            .unwrap()
            .map(|x| (base + x.t.0, x.counts))
            .collect();
        let streamed: Vec<_> = s.iter().filter(|x| x.3 == cond).collect();
        let mut at = 0;
        for (_, ap, sums, _) in &streamed {
            assert!((6..=7).contains(&ap.len()), "{} conversions", ap.len());
            let mut want = [0i32; 3];
            for t in ap.ticks() {
                // The 32-bit counter wrapped once, in the first condition.
                let t = t.0 & 0xFFFF_FFFF;
                assert_eq!(conv[at].0 & 0xFFFF_FFFF, t);
                for c in 0..3 {
                    want[c] += i32::from(conv[at].1[c]);
                }
                at += 1;
            }
            assert_eq!(*sums, want);
        }
        assert!(
            (1..=7).contains(&(conv.len() - at)),
            "{} left",
            conv.len() - at
        );
    }
    assert!(s[0].1.first().0 >= 0xFFFF_0000);
    let st = dev.status();
    assert_eq!(st.state, RunState::Complete);
    assert_eq!(st.lost, 0);
    assert_eq!(
        (st.ring_oldest, st.ring_newest),
        (STREAMED - RING as u32, STREAMED - 1)
    );
}

/// σ_CRLB of A, B, C for white noise over `n` conversions (quantisation included).
fn sigma_crlb(n: usize) -> [f64; 3] {
    let s2 = crosscheck::noise_sigma(104_000).powi(2) + 1.0 / 12.0;
    let n = n as f64;
    [
        (2.0 * s2 / n).sqrt(),
        (2.0 * s2 / n).sqrt(),
        (s2 / n).sqrt(),
    ]
}

/// Every fit report, periodic and final, against an f64 fit of exactly the samples of its
/// window (their sums and conversion instants), with the step it reports: within 1e-5
/// σ_CRLB of all the window's conversions. The final ones also equal a direct f32 fit bit
/// for bit.
#[test]
fn fit_reports_match_f64_fits_of_their_windows() {
    let (packets, _) = run_paper();
    let s = samples(&packets);
    let mut finals = 0;
    let mut periodic = 0;
    let mut worst = 0.0f64;
    for p in &packets {
        let Packet::Fit(f) = p else { continue };
        let window: Vec<_> = s
            .iter()
            .filter(|x| x.0 >= f.first_seq && x.0 <= f.last_seq)
            .collect();
        assert_eq!(window.len(), f.n as usize);
        assert!(window.iter().all(|x| x.3 == f.condition));
        let step = PhaseStep(f.step);
        assert_eq!(
            PhaseStep::from_micro_hz(u64::from(f.rate_uhz), TickRate::MHZ_1),
            Some(step)
        );
        let mut f64_fit = SineFit::<f64>::new(FitConfig::sine(step, TickRate::MHZ_1));
        let mut f32_fit = SineFit::<f32>::new(FitConfig::sine(step, TickRate::MHZ_1));
        for x in &window {
            f64_fit.update_sum(&x.1, x.2.map(f64::from)).unwrap();
            f32_fit.update_sum(&x.1, x.2.map(|v| v as f32)).unwrap();
        }
        let r = f64_fit.solve().unwrap();
        let crlb = sigma_crlb(window.iter().map(|x| x.1.len()).sum());
        for ch in 0..3 {
            for (k, param) in [Param::A, Param::B, Param::C].into_iter().enumerate() {
                let host = r.coef(ch, param).unwrap().to_f64();
                let d = (f.coef[ch][k] - host).abs() / crlb[k];
                worst = worst.max(d);
                let se = r.se(ch, param).unwrap();
                assert!(
                    (f64::from(f.se[ch][k]) - se).abs() <= 1e-4 * se,
                    "se {ch} {k}"
                );
            }
        }
        if f.is_final {
            finals += 1;
            let d = f32_fit.solve().unwrap();
            let direct = rotacal_shared::device::session::report(
                &d,
                f.condition,
                true,
                f.first_seq,
                f.last_seq,
                f.rate_uhz,
                step,
            );
            assert_eq!(&direct, f);
        } else {
            periodic += 1;
        }
    }
    println!("worst |f32 − f64| / σ_CRLB over {finals} final and {periodic} periodic reports: {worst:.2e}");
    assert_eq!(finals, 3);
    // 4199 samples per condition, a report every 160 once the fit spans 1.5 periods.
    assert!(periodic >= 3 * 10, "{periodic} periodic reports");
    // Issue 15's bound for averaged samples. Coefficients travel as exact f64.
    assert!(worst <= 1e-5, "{worst}");
}

/// The quick-look equals the Gram computation on f64 fits of the same windows to 1e-4 of
/// its own uncertainty, and agrees with the simulated truth.
#[test]
fn quick_look_matches_the_host_and_the_truth() {
    let (packets, dev) = run_paper();
    let q = dev.quick_look().unwrap();
    assert_eq!(
        packets
            .iter()
            .filter(|p| matches!(p, Packet::QuickLook(_)))
            .count(),
        1
    );
    let s = samples(&packets);
    let fits: Vec<_> = Condition::ALL
        .iter()
        .map(|c| {
            let step = PhaseStep::from_micro_hz(10_000, TickRate::MHZ_1).unwrap();
            let mut f = SineFit::<f64>::new(FitConfig::sine(step, TickRate::MHZ_1));
            for x in s.iter().filter(|x| x.3 == *c) {
                f.update_sum(&x.1, x.2.map(f64::from)).unwrap();
            }
            rotacal_shared::intrinsic::ConditionFit::from_fit(&f.solve().unwrap())
        })
        .collect();
    let host =
        rotacal_shared::intrinsic::from_gram(&[fits[0], fits[1], fits[2]], 9.80665, 0.0).unwrap();
    let truth = crosscheck::sensitivity();
    for j in 0..3 {
        let h = host.sensitivity[j];
        let d = (q.sensitivity[j] - h.value).abs();
        assert!(
            d <= 1e-4 * h.std_unc,
            "s{j}: {} vs {}",
            q.sensitivity[j],
            h.value
        );
        assert!((f64::from(q.sensitivity_u[j]) - h.std_unc).abs() <= 1e-3 * h.std_unc);
        let t = truth[j].iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((h.value - t).abs() <= 5.0 * h.std_unc, "s{j} vs truth {t}");
        let a = host.angle_deg[j];
        assert!((q.angle_deg[j] - a.value).abs() <= 1e-4 * a.std_unc);
    }
    assert_eq!(q.g_loc, 9.80665);
}

fn collect(
    dev: &mut Device<RING>,
    f: impl FnOnce(&mut Device<RING>, &mut dyn FnMut(Packet)),
) -> Vec<Packet> {
    let mut v = Vec::new();
    f(dev, &mut |p| v.push(p));
    v
}

fn last_status(p: &[Packet]) -> Status {
    match p.last() {
        Some(Packet::Status(s)) => *s,
        other => panic!("expected a status, got {other:?}"),
    }
}

/// The packets a Backfill of `count` samples from `from_seq` brings.
fn backfill(dev: &mut Device<RING>, from_seq: u32, count: u16) -> Vec<Packet> {
    collect(dev, |d, o| {
        d.on_command(Command::Backfill { from_seq, count }, &mut |x| o(x))
    })
}

/// Start condition x at 0.01 Hz.
const START_X: Command = Command::Start {
    condition: Condition::X,
    rate_uhz: 10_000,
};

#[test]
fn commands_are_checked_and_refusals_reported() {
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let start = START_X;
    let p = collect(&mut dev, |d, o| d.on_command(Command::Stop, &mut |x| o(x)));
    assert_eq!(last_status(&p).last_error, Some(CommandError::NotRunning));
    let p = collect(&mut dev, |d, o| {
        d.on_command(
            Command::Start {
                condition: Condition::X,
                rate_uhz: 0,
            },
            &mut |x| o(x),
        )
    });
    assert_eq!(last_status(&p).last_error, Some(CommandError::BadRate));
    let p = collect(&mut dev, |d, o| {
        d.on_command(Command::SetSampleRate { mhz: 200_000 }, &mut |x| o(x))
    });
    assert_eq!(
        last_status(&p).last_error,
        Some(CommandError::BadRate),
        "above the sensor's rate"
    );
    let p = collect(&mut dev, |d, o| d.on_command(start, &mut |x| o(x)));
    let st = last_status(&p);
    assert_eq!(
        (st.state, st.last_error, st.condition),
        (RunState::Running, None, Some(Condition::X))
    );
    let p = collect(&mut dev, |d, o| d.on_command(start, &mut |x| o(x)));
    assert_eq!(last_status(&p).last_error, Some(CommandError::Busy));
    let p = collect(&mut dev, |d, o| {
        d.on_command(Command::SetSampleRate { mhz: 26_000 }, &mut |x| o(x))
    });
    assert_eq!(last_status(&p).last_error, Some(CommandError::Busy));
    // Stopping before 1.5 periods: no fit, nothing recorded, and the device says why.
    let p = collect(&mut dev, |d, o| {
        for i in 0..100u64 {
            d.on_sample(i * 9615, [100, 200, 300], false, &mut |x| o(x));
        }
        d.on_command(Command::Stop, &mut |x| o(x));
    });
    assert!(!p.iter().any(|x| matches!(x, Packet::Fit(_))));
    assert_eq!(last_status(&p).last_error, Some(CommandError::FitFailed));
    assert_eq!(last_status(&p).state, RunState::Idle);
    // A failing sensor refuses Start, with a status on the change.
    let p = collect(&mut dev, |d, o| {
        d.on_sensor_status(SensorStatus::BusError, &mut |x| o(x));
        d.on_command(start, &mut |x| o(x));
    });
    assert_eq!(p.len(), 2);
    let st = last_status(&p);
    assert_eq!(
        (st.sensor, st.last_error),
        (SensorStatus::BusError, Some(CommandError::SensorFault))
    );
    // Samples while idle are not streamed and don't use sequence numbers.
    let p = collect(&mut dev, |d, o| {
        d.on_sensor_status(SensorStatus::Ok, &mut |x| o(x));
        for i in 0..50u64 {
            d.on_sample(10_000_000 + i * 9615, [1, 2, 3], false, &mut |x| o(x));
        }
    });
    assert!(p.iter().all(|x| matches!(x, Packet::Status(_))));
}

#[test]
fn backfill_resends_from_the_ring() {
    let (live, mut dev) = run_paper();
    let p = backfill(&mut dev, 12_500, 60);
    assert_eq!(last_status(&p).last_error, None);
    let seqs: Vec<u32> = p
        .iter()
        .filter_map(|x| {
            if let Packet::Averages(b) = x {
                Some(b)
            } else {
                None
            }
        })
        .inspect(|b| assert!(b.replay && b.condition == Condition::Z))
        .flat_map(|b| b.iter().map(|(s, _, _)| s).collect::<Vec<_>>())
        .collect();
    assert_eq!(seqs, (12_500..12_560).collect::<Vec<_>>());
    // The ring's packed entries give back the live samples exactly.
    let replayed: Vec<_> = p
        .iter()
        .filter_map(|x| match x {
            Packet::Averages(b) => Some(b),
            _ => None,
        })
        .flat_map(|b| b.iter().map(|(seq, ap, s)| (seq, ap, s.sums, b.condition)))
        .collect();
    let sent = samples(&live);
    let from = sent.iter().position(|x| x.0 == 12_500).unwrap();
    assert_eq!(replayed, sent[from..from + 60]);
    // Older than the ring holds: what is left is sent, and the refusal says so.
    let oldest = STREAMED - RING as u32;
    let p = backfill(&mut dev, oldest - 10, 20);
    assert_eq!(last_status(&p).last_error, Some(CommandError::NotInRing));
    let n: usize = p
        .iter()
        .map(|x| {
            if let Packet::Averages(b) = x {
                b.len()
            } else {
                0
            }
        })
        .sum();
    assert_eq!(n, 10);
}

/// A backfill goes out as the link has room: never more packets than the room given, the
/// same batches as all at once, and the status reply only after the last of them (and only
/// when the results queue has a place).
#[test]
fn a_backfill_is_paced_by_the_room_and_its_status_comes_last() {
    use rotacal_shared::device::route::{Characteristic, Room, RESULTS_QUEUE, STREAM_QUEUE};
    let (_, dev) = run_paper();
    let cmd = Command::Backfill {
        from_seq: STREAMED - 300,
        count: 300,
    };
    let mut all_at_once = Vec::new();
    dev.clone().on_command(cmd, &mut |x| all_at_once.push(x));
    let mut dev = dev;
    let mut paced = Vec::new();
    dev.command(cmd, &mut |x| paced.push(x));
    assert!(paced.is_empty());
    let mut pumps = 0;
    loop {
        pumps += 1;
        assert!(pumps < 1000, "the replay never ends");
        let mut now = Vec::new();
        // Two places a time, and none in the results queue for the first ten pumps.
        let room = Room {
            stream: 2,
            results: usize::from(pumps > 10),
        };
        let done = dev.pump(room, &mut |x| now.push(x));
        let stream = now
            .iter()
            .filter(|p| Characteristic::of(p) == Some(Characteristic::Stream))
            .count();
        assert!(stream <= 2, "{stream} packets for 2 places");
        paced.extend(now);
        if done {
            break;
        }
    }
    assert_eq!(paced, all_at_once);
    assert!(matches!(paced.last(), Some(Packet::Status(_))));
    assert_eq!(
        paced
            .iter()
            .filter(|p| matches!(p, Packet::Status(_)))
            .count(),
        1
    );
    // 300 samples in batches of 7: more batches than the firmware's stream queue holds.
    assert!(
        paced.len() > STREAM_QUEUE + RESULTS_QUEUE,
        "{}",
        paced.len()
    );
    assert!(dev.pump(Room::UNLIMITED, &mut |_| panic!("nothing is owed")));
}

/// The firmware's routing: batches of either version and temperatures to the stream
/// characteristic, fits, the quick-look and status to the results one.
#[test]
fn packets_go_to_the_firmwares_characteristics() {
    use rotacal_shared::device::route::Characteristic;
    let (p, _) = run_paper();
    for x in &p {
        let want = match x {
            Packet::Samples(_) | Packet::Averages(_) | Packet::Temperature(_) => {
                Characteristic::Stream
            }
            Packet::Info(_) => Characteristic::Info,
            _ => Characteristic::Results,
        };
        assert_eq!(Characteristic::of(x), Some(want), "{x:?}");
    }
    assert!(p.iter().any(|x| matches!(x, Packet::Averages(_))));
    assert_eq!(Characteristic::of(&Packet::Command(Command::Stop)), None);
}

#[test]
fn a_part_filled_batch_waits_at_most_max_batch_age() {
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let mut p = Vec::new();
    dev.on_command(
        Command::Start {
            condition: Condition::Y,
            rate_uhz: 10_000,
        },
        &mut |x| p.push(x),
    );
    p.clear();
    for i in 0..40u64 {
        dev.on_sample(i * 9_615, [0, 0, 16_000], false, &mut |x| p.push(x));
    }
    // 40 conversions = 0.38 s: 5 slots closed (the sixth is open), not yet a second old.
    dev.poll(400_000, &mut |x| p.push(x));
    assert!(p.is_empty());
    dev.poll(1_000_000, &mut |x| p.push(x));
    match p.as_slice() {
        [Packet::Averages(b)] => {
            assert_eq!(b.len(), 5);
            assert_eq!(b.samples()[0].flags, 0);
            assert_eq!(b.samples()[0].sums, [0, 0, 7 * 16_000]);
        }
        other => panic!("{other:?}"),
    }
    // One rail reading flags its slot as clipped; one missed edge flags it late. The
    // eighth conversion falls in the next slot and closes this one.
    p.clear();
    for i in 0..8u64 {
        let rail = if i == 3 { i16::MAX } else { 0 };
        dev.on_sample(2_000_000 + i * 9_615, [rail, 0, 0], i == 0, &mut |x| {
            p.push(x)
        });
    }
    dev.on_command(Command::Stop, &mut |x| p.push(x));
    let b = p
        .iter()
        .find_map(|x| {
            if let Packet::Averages(b) = x {
                Some(*b)
            } else {
                None
            }
        })
        .unwrap();
    let last = b.samples().last().unwrap();
    assert_eq!(last.count, 7);
    assert_eq!(last.sums, [i32::from(i16::MAX), 0, 0]);
    assert_eq!(
        last.flags,
        SampleFlags::CLIPPED | SampleFlags::LATE_TIMESTAMP
    );
}

#[test]
fn batches_are_sized_to_the_links_mtu_and_carry_the_same_samples() {
    use rotacal_shared::device::route::{batch_len, payload, MIN_MTU};
    let (full, _) = run_paper_at(247);
    for mtu in [185, 158, MIN_MTU] {
        let (p, _) = run_paper_at(mtu);
        let n = batch_len(mtu).unwrap();
        for x in &p {
            assert!(x.encoded_len() <= payload(mtu), "MTU {mtu}: {x:?}");
            if let Packet::Averages(b) = x {
                assert!(b.len() <= n, "MTU {mtu}: {} samples", b.len());
            }
        }
        assert!(
            p.iter()
                .any(|x| matches!(x, Packet::Averages(b) if b.len() == n)),
            "MTU {mtu}: full batches of {n}"
        );
        assert_eq!(samples(&p), samples(&full), "MTU {mtu}");
    }
}

#[test]
fn a_smaller_mtu_splits_the_open_batch_and_below_the_least_work_is_refused() {
    use rotacal_shared::device::route::MIN_MTU;
    let mut dev = Device::<RING>::new(Config::FEATHER);
    let start = START_X;
    let p = collect(&mut dev, |d, o| d.on_command(start, &mut |x| o(x)));
    assert_eq!(last_status(&p).last_error, None);
    // Six 16 Hz samples into the open batch (seven close it at MTU 247).
    let mut live = Vec::new();
    let mut t = 1_000u64;
    while samples(&live).len() + open_len(&mut dev) < 6 {
        dev.on_sample(t, [100, -200, 300], false, &mut |x| live.push(x));
        t += 9_615;
    }
    assert!(live.is_empty(), "{live:?}");
    // MTU 158 carries 4: a batch of 4 goes, 2 stay open, and go at the next flush.
    let split = collect(&mut dev, |d, o| d.set_link_mtu(158, &mut |x| o(x)));
    let lens: Vec<usize> = split
        .iter()
        .map(|x| match x {
            Packet::Averages(b) => b.len(),
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(lens, [4]);
    let rest = collect(&mut dev, |d, o| d.on_command(Command::Stop, &mut |x| o(x)));
    let all: Vec<_> = samples(&split).into_iter().chain(samples(&rest)).collect();
    assert_eq!(
        all.iter().map(|s| s.0).collect::<Vec<_>>(),
        (0..6).collect::<Vec<_>>()
    );

    // Below MIN_MTU: Start and Backfill are refused, and say why.
    for mtu in [MIN_MTU - 1, 23] {
        let p = collect(&mut dev, |d, o| {
            d.set_link_mtu(mtu, &mut |x| o(x));
            d.on_command(start, &mut |x| o(x));
        });
        assert_eq!(last_status(&p).last_error, Some(CommandError::MtuTooSmall));
        let p = backfill(&mut dev, 0, 6);
        assert_eq!(last_status(&p).last_error, Some(CommandError::MtuTooSmall));
        assert_eq!(p.len(), 1, "only the status: {p:?}");
    }
}

/// Samples in the device's open live batch: those a Stop-less flush would send.
fn open_len(dev: &mut Device<RING>) -> usize {
    let mut probe = dev.clone();
    let mut v = Vec::new();
    probe.poll(u64::MAX / 2, &mut |x| v.push(x));
    samples(&v).len()
}
