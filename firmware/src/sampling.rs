//! The sensor side: the data-ready edge on INT1 (P1.11) is latched in hardware by
//! GPIOTE → PPI → TIMER1 CAPTURE[0], so a sample's time is its conversion time whatever
//! the task latency (method.md §7). TIMER1 runs at 1 MHz from HFCLK, which main() puts on
//! the crystal. The task reads the sample over I²C and hands (capture, counts) to the
//! logic task.

use crate::events::{Event, EVENTS};
use defmt::{info, warn};
use embassy_nrf::gpiote::InputChannel;
use embassy_nrf::peripherals::{TIMER1, TWISPI0};
use embassy_nrf::timer::Timer;
use embassy_nrf::twim::{self, Twim};
use embassy_time::{with_timeout, Duration, Timer as Delay};
use rotacal_sensor::{Accelerometer, Chip, Error};
use rotacal_shared::packet::SensorStatus;

/// Temperature every this many sensor samples (about 1 s at 104 Hz).
const TEMPERATURE_EVERY: u32 = 104;
/// No edge for this long (about 10 sensor periods) means the sensor stopped.
const DRDY_TIMEOUT: Duration = Duration::from_millis(100);

fn status_of(e: Error<twim::Error>) -> SensorStatus {
    match e {
        Error::Bus(_) => SensorStatus::BusError,
        Error::Absent => SensorStatus::Absent,
        Error::UnknownChip(_) => SensorStatus::UnknownChip,
    }
}

fn send(e: Event) {
    // A full queue loses this event; the logic task counts samples it never saw as lost
    // from the gap it leaves (the ring and the sequence numbers make that visible).
    if EVENTS.try_send(e).is_err() {
        crate::events::note_overflow();
    }
}

/// Find the sensor (retrying every second), then sample forever. Never panics: every
/// failure becomes a status the host sees.
#[embassy_executor::task]
pub async fn sensor_task(
    timer: Timer<'static, TIMER1>,
    drdy: InputChannel<'static>,
    mut bus: Twim<'static, TWISPI0>,
) {
    loop {
        let mut acc = match Accelerometer::detect(bus) {
            Ok(a) => a,
            Err((b, e)) => {
                warn!("accelerometer: {}", e);
                bus = b;
                send(Event::Sensor(status_of(e), None));
                Delay::after_secs(1).await;
                continue;
            }
        };
        let chip = acc.chip();
        info!("accelerometer {} at {:#x}", chip, acc.address());
        send(Event::Sensor(SensorStatus::Ok, Some(chip)));
        // A latched data-ready line (LSM6DS33) stays high until the outputs are read:
        // read once so that the first edge comes.
        let _ = acc.read_counts();
        let mut n: u32 = 0;
        let mut stalled = false;
        let failure = loop {
            let waited = with_timeout(DRDY_TIMEOUT, drdy.wait()).await;
            let late = waited.is_err();
            if late && !drdy_high(&drdy) {
                if !stalled {
                    stalled = true;
                    send(Event::Sensor(SensorStatus::NoDataReady, Some(chip)));
                }
                send(Event::Poll(timer.cc(1).capture()));
                continue;
            }
            if stalled {
                stalled = false;
                send(Event::Sensor(SensorStatus::Ok, Some(chip)));
            }
            // CAPTURE[0] holds the edge's time (PPI); with a missed edge, read the time now.
            let capture = if late {
                timer.cc(1).capture()
            } else {
                timer.cc(0).read()
            };
            match acc.read_counts() {
                Ok(counts) => send(Event::Sample {
                    capture,
                    counts,
                    late,
                }),
                Err(e) => break e,
            }
            n = n.wrapping_add(1);
            if n % TEMPERATURE_EVERY == 0 {
                match acc.read_temperature_centi_c() {
                    Ok(t) => send(Event::Temperature(t)),
                    Err(e) => break e,
                }
            }
        };
        warn!("accelerometer failed: {}", failure);
        send(Event::Sensor(status_of(failure), Some(chip)));
        bus = acc.release();
        Delay::after_millis(200).await;
    }
}

fn drdy_high(drdy: &InputChannel<'static>) -> bool {
    embedded_hal::digital::v2::InputPin::is_high(drdy).unwrap_or(false)
}

/// Chip code for the device info.
pub fn chip_code(c: Option<Chip>) -> rotacal_shared::packet::Chip {
    match c {
        None => rotacal_shared::packet::Chip::None,
        Some(Chip::Lsm6ds33) => rotacal_shared::packet::Chip::Lsm6ds33,
        Some(Chip::Lsm6ds3trc) => rotacal_shared::packet::Chip::Lsm6ds3trc,
    }
}
