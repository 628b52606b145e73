//! The packet protocol: every packet survives encode → decode unchanged, and the decoder
//! never panics on arbitrary bytes; whatever it accepts re-encodes to the same bytes (one
//! encoding per packet), so nothing is silently dropped or altered.

// A test reports failure by panicking; the crate itself (src/) allows none of these.
#![allow(clippy::unwrap_used, clippy::indexing_slicing)]

use proptest::prelude::*;
use rotacal_shared::packet::*;
use rotacal_shared::{Aperture, Condition, Ticks, MAX_CONVERSIONS};

fn condition() -> impl Strategy<Value = Condition> {
    prop_oneof![Just(Condition::X), Just(Condition::Y), Just(Condition::Z)]
}

fn f32x3() -> impl Strategy<Value = [f32; 3]> {
    // Any bit pattern, NaNs included: compared through their encodings below.
    prop::array::uniform3(any::<u32>().prop_map(f32::from_bits))
}

fn f64x3() -> impl Strategy<Value = [f64; 3]> {
    prop::array::uniform3(any::<u64>().prop_map(f64::from_bits))
}

fn batch() -> impl Strategy<Value = SampleBatch> {
    (
        condition(),
        any::<bool>(),
        any::<u32>(),
        any::<u64>(),
        prop::collection::vec(
            (
                any::<u32>(),
                prop::array::uniform3(any::<i16>()),
                0..=SampleFlags::ALL,
            ),
            1..=MAX_SAMPLES,
        ),
    )
        .prop_map(|(c, replay, seq, t0, samples)| {
            let mut b = SampleBatch::new(c, replay, seq, t0);
            for (dt, counts, flags) in samples {
                b.push(t0.wrapping_add(u64::from(dt)), counts, flags).ok();
            }
            b
        })
        .prop_filter("at least one sample", |b| !b.is_empty())
}

fn averages() -> impl Strategy<Value = AverageBatch> {
    (
        condition(),
        any::<bool>(),
        any::<u32>(),
        any::<u64>(),
        prop::collection::vec(
            (
                any::<u32>(),
                prop::collection::vec(1..=u16::MAX, 0..MAX_CONVERSIONS),
                prop::array::uniform3(any::<i16>()),
                0..=SampleFlags::ALL,
            ),
            1..=MAX_AVERAGES,
        ),
    )
        .prop_map(|(c, replay, seq, t0, samples)| {
            let mut b = AverageBatch::new(c, replay, seq, t0);
            for (dt, gaps, reading, flags) in samples {
                let ap = Aperture::new(Ticks(t0.wrapping_add(u64::from(dt))), &gaps).unwrap();
                // A sum of len readings: any value in that range.
                let sums = reading.map(|r| i32::from(r) * ap.len() as i32);
                b.push(&ap, sums, flags).ok();
            }
            b
        })
        .prop_filter("at least one sample", |b| !b.is_empty())
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        (condition(), 1..=u32::MAX).prop_map(|(condition, rate_uhz)| Command::Start {
            condition,
            rate_uhz
        }),
        Just(Command::Stop),
        (1..=u32::MAX).prop_map(|mhz| Command::SetSampleRate { mhz }),
        Just(Command::Reset),
        (any::<u32>(), any::<u16>())
            .prop_map(|(from_seq, count)| Command::Backfill { from_seq, count }),
    ]
}

fn packet() -> impl Strategy<Value = Packet> {
    prop_oneof![
        batch().prop_map(Packet::Samples),
        averages().prop_map(Packet::Averages),
        (any::<u32>(), any::<i16>())
            .prop_map(|(seq, centi_c)| Packet::Temperature(Temperature { seq, centi_c })),
        (
            condition(),
            any::<bool>(),
            prop::array::uniform5(any::<u32>()),
            any::<u64>(),
            prop::array::uniform3(f64x3()),
            prop::array::uniform3(f32x3()),
            f32x3(),
        )
            .prop_map(|(condition, is_final, w, step, coef, se, rms)| {
                Packet::Fit(FitReport {
                    condition,
                    is_final,
                    n: w[0],
                    first_seq: w[1],
                    last_seq: w[2],
                    rate_uhz: w[3],
                    step,
                    coef,
                    se,
                    rms,
                })
            }),
        (f64x3(), f32x3(), f64x3(), f32x3(), any::<u64>()).prop_map(|(s, su, a, au, g)| {
            Packet::QuickLook(QuickLook {
                sensitivity: s,
                sensitivity_u: su,
                angle_deg: a,
                angle_u: au,
                g_loc: f64::from_bits(g),
            })
        }),
        (
            prop::array::uniform3(any::<u8>()),
            prop_oneof![
                Just(Chip::None),
                Just(Chip::Lsm6ds33),
                Just(Chip::Lsm6ds3trc)
            ],
            prop_oneof![
                Just(ClockSource::TimerHfxo),
                Just(ClockSource::RtcLfrc),
                Just(ClockSource::TimerHfint)
            ],
            prop::array::uniform3(any::<u32>()),
            any::<u8>(),
            any::<u16>(),
        )
            .prop_map(|(firmware, chip, clock, r, full_scale_g, ring_capacity)| {
                Packet::Info(DeviceInfo {
                    firmware,
                    chip,
                    clock,
                    tick_hz: r[0],
                    sensor_odr_mhz: r[1],
                    sample_rate_mhz: r[2],
                    full_scale_g,
                    ring_capacity,
                })
            }),
        (
            prop_oneof![
                Just(RunState::Idle),
                Just(RunState::Running),
                Just(RunState::Complete)
            ],
            prop_oneof![
                Just(SensorStatus::Ok),
                Just(SensorStatus::Absent),
                Just(SensorStatus::UnknownChip),
                Just(SensorStatus::BusError),
                Just(SensorStatus::NoDataReady)
            ],
            prop::option::of(condition()),
            prop::array::uniform3(any::<u32>()),
            prop::option::of(prop_oneof![
                Just(CommandError::Busy),
                Just(CommandError::NotRunning),
                Just(CommandError::BadRate),
                Just(CommandError::SensorFault),
                Just(CommandError::NotInRing),
                Just(CommandError::FitFailed)
            ]),
        )
            .prop_map(|(state, sensor, condition, r, last_error)| {
                Packet::Status(Status {
                    state,
                    sensor,
                    condition,
                    lost: r[0],
                    ring_oldest: r[1],
                    ring_newest: r[2],
                    last_error,
                })
            }),
        command().prop_map(Packet::Command),
    ]
}

/// CRC-16/IBM-SDLC (X.25), bit by bit: an implementation of the version 3 CRC other than
/// the crc crate's table (check value 0x906E on "123456789").
fn x25(data: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in data {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x8408
            } else {
                crc >> 1
            };
        }
    }
    crc ^ 0xFFFF
}

#[test]
fn the_crc_is_x25_and_ends_every_version_3_packet() {
    assert_eq!(x25(b"123456789"), 0x906E);
    let b = {
        let mut b = AverageBatch::new(Condition::X, false, 3, 0);
        b.push(&Aperture::point(Ticks(5)), [1, 2, 3], 0).unwrap();
        b
    };
    for p in [
        Packet::Averages(b),
        Packet::Command(Command::Stop),
        Packet::Status(Status {
            state: RunState::Idle,
            sensor: SensorStatus::Ok,
            condition: None,
            lost: 0,
            ring_oldest: 0,
            ring_newest: 0,
            last_error: None,
        }),
    ] {
        let bytes = encode(&p);
        let n = bytes.len() - 2;
        assert_eq!(bytes[0], 3);
        assert_eq!(
            u16::from_le_bytes([bytes[n], bytes[n + 1]]),
            x25(&bytes[..n])
        );
    }
}

fn encode(p: &Packet) -> Vec<u8> {
    let mut buf = [0u8; MAX_PACKET];
    let n = p.encode(&mut buf).unwrap();
    assert_eq!(n, p.encoded_len());
    assert!(
        n <= 244,
        "every packet fits one notification at ATT MTU 247"
    );
    buf[..n].to_vec()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(5000))]

    #[test]
    fn round_trip(p in packet()) {
        let bytes = encode(&p);
        let back = Packet::decode(&bytes).unwrap();
        // Bytes compare NaNs exactly; PartialEq would not.
        prop_assert_eq!(encode(&back), bytes);
        prop_assert_eq!(format!("{back:?}"), format!("{p:?}"));
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        if let Ok(p) = Packet::decode(&bytes) {
            prop_assert_eq!(encode(&p), bytes);
        }
    }

    /// Mostly-valid packets with one byte changed or the length cut: the decoder's
    /// checks are exercised far more often than by uniform bytes.
    #[test]
    fn mutated_packets_never_panic(p in packet(), at in any::<prop::sample::Index>(), to in any::<u8>(), cut in any::<bool>()) {
        let mut bytes = encode(&p);
        let i = at.index(bytes.len());
        if cut {
            bytes.truncate(i);
        } else {
            bytes[i] = to;
        }
        if let Ok(q) = Packet::decode(&bytes) {
            prop_assert_eq!(encode(&q), bytes);
        }
    }
}

#[test]
fn errors_say_what_and_where() {
    assert_eq!(
        Packet::decode(&[]),
        Err(DecodeError::TooShort { need: 4, got: 0 })
    );
    assert_eq!(Packet::decode(&[9, 1, 1, 1]), Err(DecodeError::Version(9)));
    // Version 3 needs its CRC after the header at least.
    assert_eq!(
        Packet::decode(&[3, 1, 1, 1]),
        Err(DecodeError::TooShort { need: 6, got: 4 })
    );
    // Version 2 is the averaged samples' layout only.
    assert_eq!(Packet::decode(&[2, 3, 1, 1]), Err(DecodeError::Version(2)));
    assert_eq!(
        Packet::decode(&[2, 1, 1, 1]),
        Err(DecodeError::TooShort { need: 46, got: 4 })
    );
    assert_eq!(
        Packet::decode(&[1, 0x7f, 0, 0]),
        Err(DecodeError::Kind(0x7f))
    );
    let start = encode(&Packet::Command(Command::Start {
        condition: Condition::Y,
        rate_uhz: 10_000,
    }));
    // Version 3: the layout, then its CRC-16/IBM-SDLC (X.25), little-endian: 0xF8A3, as an
    // independent bitwise computation gives (its check value on "123456789" is 0x906E).
    assert_eq!(start, [3, 0x10, 2, 0, 0x10, 0x27, 0, 0, 0xA3, 0xF8]);
    // Any bit flipped is refused as corrupted, never read as another packet.
    for i in 0..start.len() * 8 {
        let mut flipped = start.clone();
        flipped[i / 8] ^= 1 << (i % 8);
        // (A flip in the version byte can make it an old version's, whose layout is
        // then refused by its length.)
        let got = Packet::decode(&flipped);
        assert!(got.is_err(), "bit {i}: {got:?}");
    }
    assert_eq!(
        format!(
            "{}",
            Packet::decode(&[3, 0x10, 2, 0, 0x10, 0x27, 0, 0, 0, 0]).unwrap_err()
        ),
        "corrupted: its CRC-16 is 0000, its bytes' f8a3"
    );
    // The layouts' own checks, on version 1 (no CRC, as old captures hold it).
    let start = vec![1, 0x10, 2, 0, 0x10, 0x27, 0, 0];
    assert!(matches!(
        Packet::decode(&start),
        Ok(Packet::Command(Command::Start {
            condition: Condition::Y,
            rate_uhz: 10_000
        }))
    ));
    let mut bad = start.clone();
    bad[2] = 4;
    assert_eq!(
        Packet::decode(&bad),
        Err(DecodeError::Field {
            offset: 2,
            name: "condition"
        })
    );
    let mut long = start.clone();
    long.push(0);
    assert_eq!(
        Packet::decode(&long),
        Err(DecodeError::TooLong { want: 8, got: 9 })
    );
    assert_eq!(
        Packet::decode(&start[..6]),
        Err(DecodeError::TooShort { need: 8, got: 6 })
    );
    let msg = format!(
        "{}",
        DecodeError::Field {
            offset: 2,
            name: "condition"
        }
    );
    assert_eq!(msg, "byte 2: condition out of range");
}

#[test]
fn a_full_batch_has_the_documented_layout() {
    let mut b = SampleBatch::new(Condition::Z, true, 7, 1_000_000);
    for i in 0..MAX_SAMPLES as u64 {
        b.push(1_000_000 + 62_500 * i, [1, -2, 3], 0).unwrap();
    }
    assert!(b.is_full());
    assert!(b.push(2_000_000, [0; 3], 0).is_err());
    let bytes = encode(&Packet::Samples(b));
    assert_eq!(bytes.len(), 16 + 11 * MAX_SAMPLES);
    assert_eq!(&bytes[..4], &[1, 0x01, MAX_SAMPLES as u8, 0x83]);
    assert_eq!(&bytes[4..8], &7u32.to_le_bytes());
    assert_eq!(&bytes[8..16], &1_000_000u64.to_le_bytes());
    // Second sample: dt 62 500, counts 1, −2, 3, flags 0.
    assert_eq!(
        &bytes[27..38],
        &[0x24, 0xF4, 0, 0, 1, 0, 0xFE, 0xFF, 3, 0, 0]
    );
    let seqs: Vec<(u32, u64)> = b.iter().map(|(s, t, _)| (s, t)).take(2).collect();
    assert_eq!(seqs, [(7, 1_000_000), (8, 1_062_500)]);
    // Before t0, or beyond u32 ticks after it, is refused.
    let mut c = SampleBatch::new(Condition::X, false, 0, 10);
    assert!(c.push(9, [0; 3], 0).is_err());
    assert!(c.push(10 + (1u64 << 32), [0; 3], 0).is_err());
}

#[test]
fn an_averaged_batch_has_the_documented_layout() {
    let mut b = AverageBatch::new(Condition::Y, false, 9, 5_000);
    let ap = Aperture::new(Ticks(5_100), &[9_615, 9_616, 9_615, 9_615, 9_616, 9_615]).unwrap();
    b.push(&ap, [7, -14, 114_688], SampleFlags::CLIPPED)
        .unwrap();
    let short = Aperture::new(Ticks(67_600), &[9_615]).unwrap();
    b.push(&short, [-65_536, 0, 1], 0).unwrap();
    let bytes = encode(&Packet::Averages(b));
    assert_eq!(bytes.len(), 16 + 30 * 2 + 2);
    assert_eq!(&bytes[..4], &[3, 0x01, 2, 0x02]);
    assert_eq!(&bytes[4..8], &9u32.to_le_bytes());
    assert_eq!(&bytes[8..16], &5_000u64.to_le_bytes());
    // First sample: dt 100, 7 conversions, flags 1, sums, six gaps.
    assert_eq!(&bytes[16..22], &[100, 0, 0, 0, 7, 1]);
    assert_eq!(&bytes[22..26], &7i32.to_le_bytes());
    assert_eq!(&bytes[26..30], &(-14i32).to_le_bytes());
    assert_eq!(&bytes[30..34], &114_688i32.to_le_bytes());
    assert_eq!(&bytes[34..36], &9_615u16.to_le_bytes());
    // Second sample: two conversions, one gap, the other five 0.
    assert_eq!(&bytes[46..52], &[0x88, 0xF4, 0, 0, 2, 0]);
    assert_eq!(&bytes[64..76], &[0x8F, 0x25, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    let back: Vec<_> = b.iter().map(|(seq, ap, s)| (seq, ap, s.sums)).collect();
    assert_eq!(back[0], (9, ap, [7, -14, 114_688]));
    assert_eq!(back[1], (10, short, [-65_536, 0, 1]));
    // A sum beyond its conversions' range, an unused gap set or a used one 0, a count
    // beyond 7: refused, naming the byte.
    let refused = |at: usize, value: &[u8], offset: usize, name: &'static str| {
        let mut bad = bytes.clone();
        bad[at..at + value.len()].copy_from_slice(value);
        // Changed bytes with a good CRC: what the layout's own checks see.
        let n = bad.len() - 2;
        let crc = x25(&bad[..n]);
        bad[n..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(
            Packet::decode(&bad),
            Err(DecodeError::Field { offset, name })
        );
    };
    refused(52, &(-65_537i32).to_le_bytes(), 52, "sum of counts");
    refused(66, &[1], 66, "conversion gap");
    refused(34, &[0, 0], 34, "conversion gap");
    refused(20, &[8], 20, "conversion count");
}
