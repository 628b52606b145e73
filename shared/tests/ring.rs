//! The backfill ring's packed entries: what goes in comes out, across counter wraps, long
//! pauses, gaps in the sequence and a full ring.
#![allow(clippy::unwrap_used, clippy::indexing_slicing, clippy::panic)]

use proptest::prelude::*;
use rotacal_shared::device::ring::{Entry, Ring};
use rotacal_shared::device::sampler::StreamSample;
use rotacal_shared::time::MAX_CONVERSIONS;
use rotacal_shared::{Aperture, Condition, Ticks};

fn entry(seq: u32, first: u64, gaps: &[u16], sums: [i32; 3], flags: u8, c: Condition) -> Entry {
    Entry {
        sample: StreamSample {
            seq,
            aperture: Aperture::new(Ticks(first), gaps).unwrap(),
            sums,
            flags,
        },
        condition: c,
    }
}

/// A run of consecutive samples 62 500 ticks apart (16 Hz on a 1 MHz clock) from `t0`.
fn run(seq0: u32, t0: u64, n: u32) -> Vec<Entry> {
    (0..n)
        .map(|i| {
            let c = Condition::ALL[(i % 3) as usize];
            let s = i as i32;
            entry(
                seq0.wrapping_add(i),
                t0 + u64::from(i) * 62_500,
                &[9615, 9616, 9615, 9616, 9615, 9616][..(i % 7) as usize],
                [s * 7, -s * 11, 229_369 - s],
                (i % 4) as u8,
                c,
            )
        })
        .collect()
}

fn held<const N: usize>(r: &Ring<N>) -> Vec<Entry> {
    r.iter().collect()
}

#[test]
fn a_full_ring_keeps_the_newest_exactly() {
    let mut r = Ring::<64>::new();
    let all = run(1000, 5_000_000, 200);
    for e in &all {
        r.push(*e);
    }
    assert_eq!(held(&r), all[136..]);
    assert_eq!(r.span(), (1136, 1199));
}

#[test]
fn times_cross_the_32_bit_boundary_and_the_seq_wraps() {
    let mut r = Ring::<64>::new();
    let all = run(u32::MAX - 20, u64::from(u32::MAX) - 1_000_000, 50);
    for e in &all {
        r.push(*e);
    }
    assert_eq!(held(&r), all[..]);
    assert_eq!(r.span(), (u32::MAX - 20, 28));
}

#[test]
fn a_pause_of_more_than_2_pow_32_ticks_drops_what_it_could_not_date() {
    let mut r = Ring::<64>::new();
    let before = run(10, 1_000, 5);
    let after = run(15, 1_000 + (1 << 32) + 200_000, 5);
    for e in before.iter().chain(&after) {
        r.push(*e);
    }
    // Only the samples within 2³² ticks of the newest are kept: none of the first run.
    assert_eq!(held(&r), after);
    // Just under 2³² ticks: all kept, dated right.
    let mut r = Ring::<64>::new();
    let after = run(15, 1_000 + u64::from(u32::MAX), 1);
    for e in before.iter().chain(&after) {
        r.push(*e);
    }
    assert_eq!(held(&r), [before.clone(), after].concat());
}

#[test]
fn a_gap_in_seq_or_time_going_back_starts_afresh() {
    let mut r = Ring::<64>::new();
    let a = run(10, 1_000_000, 5);
    let b = run(16, 2_000_000, 3);
    for e in a.iter().chain(&b) {
        r.push(*e);
    }
    assert_eq!(held(&r), b);
    let back = run(19, 1_000_000, 2);
    for e in &back {
        r.push(*e);
    }
    assert_eq!(held(&r), back);
}

#[test]
fn a_sum_beyond_24_bits_is_not_stored_wrongly() {
    let mut r = Ring::<8>::new();
    r.push(entry(1, 0, &[], [1 << 23, 0, 0], 0, Condition::X));
    assert!(r.is_empty());
    r.push(entry(
        2,
        10,
        &[],
        [-(1 << 23), (1 << 23) - 1, 0],
        0,
        Condition::Y,
    ));
    assert_eq!(held(&r)[0].sample.sums, [-(1 << 23), (1 << 23) - 1, 0]);
}

proptest! {
    #[test]
    fn every_sample_comes_back_as_it_went_in(
        seq0 in any::<u32>(),
        t0 in 0u64..(1 << 48),
        samples in prop::collection::vec(
            (1u64..200_000, prop::collection::vec(1u16.., 0..MAX_CONVERSIONS),
             prop::array::uniform3(-229_376i32..=229_369), any::<u8>(), 0usize..3),
            1..80),
    ) {
        let mut r = Ring::<48>::new();
        let mut t = t0;
        let mut pushed = Vec::new();
        for (i, (dt, gaps, sums, flags, c)) in samples.into_iter().enumerate() {
            t += dt;
            let e = entry(seq0.wrapping_add(i as u32), t, &gaps, sums, flags, Condition::ALL[c]);
            r.push(e);
            pushed.push(e);
        }
        let keep = pushed.len().min(48);
        prop_assert_eq!(held(&r), pushed[pushed.len() - keep..].to_vec());
    }
}

proptest! {
    /// A replay sends exactly the held samples in [from, from + count), whatever `from` is
    /// (inside the ring, before its oldest, after its newest, across the seq wrap).
    #[test]
    fn a_replay_sends_the_wanted_samples_held(
        seq0 in prop::sample::select(vec![0u32, 1000, u32::MAX - 30]),
        n in 1u32..80,
        from_off in -100i64..100,
        count in 0u16..120,
    ) {
        use rotacal_shared::packet::Packet;
        let mut r = Ring::<48>::new();
        for e in run(seq0, 5_000_000, n) {
            r.push(e);
        }
        let from = seq0.wrapping_add(from_off as u32);
        let end = from.wrapping_add(u32::from(count));
        let want: Vec<u32> = r
            .iter()
            .map(|e| e.sample.seq)
            .filter(|s| s.wrapping_sub(from) < end.wrapping_sub(from))
            .collect();
        let (mut replay, _) = r.replay(from, count, 7);
        let mut got = Vec::new();
        let done = replay.send(&r, usize::MAX, &mut |p| {
            if let Packet::Averages(b) = p {
                got.extend(b.iter().map(|(s, _, _)| s));
            }
        });
        prop_assert!(done);
        prop_assert_eq!(got, want);
    }
}
