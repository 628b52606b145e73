//! The sensor side: the data-ready edge on INT1 (P1.11) goes through GPIOTE and PPI
//! channel 0 to TIMER1 CAPTURE[0] (1 MHz from HFCLK, which main() puts on the crystal), so a
//! sample's time is its conversion's whatever the task latency (docs/method.md §7), and on the
//! channel's fork to TIMER2 in counter mode, which counts every edge. The task reads the
//! sample over I²C, noting the timer and the count before and after, and
//! `rotacal_shared::device::pairing` decides which instant the data belong to; the logic
//! task's device counts the conversions that were not read.
//!
//! An edge is looked for in the count, not only awaited: embassy-nrf's
//! `InputChannel::wait()` clears an event that came before it was armed, and the
//! LSM6DS33's latched line gives no new edge until it is read, so a wait alone could sit
//! out its timeout while a conversion waited.

use crate::bus::Bus;
use crate::events::{Event, EVENTS};
use defmt::{info, warn};
use embassy_nrf::gpiote::InputChannel;
use embassy_nrf::peripherals::{TIMER1, TIMER2};
use embassy_nrf::timer::Timer;
use embassy_nrf::twim;
use embassy_time::{with_timeout, Duration, Timer as Delay};
use rotacal_sensor::{Accelerometer, Chip, Error};
use rotacal_shared::device::bus_recovery::Recovery;
use rotacal_shared::device::pairing::{pair, Read};
use rotacal_shared::device::Config;
use rotacal_shared::packet::SensorStatus;

/// Temperature every this many sensor samples (about 1 s at 104 Hz).
const TEMPERATURE_EVERY: u32 = 104;
/// Look at the edge count at least this often while waiting (a little over one
/// conversion period at 104 Hz).
const LOOK_EVERY: Duration = Duration::from_millis(12);
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
    // A full queue loses this event; the device counts a conversion it never saw from the
    // time to the next one.
    if EVENTS.try_send(e).is_err() {
        crate::events::note_overflow();
    }
}

/// Find the sensor (retrying every second), then sample forever. Never panics: every
/// failure becomes a status the host sees.
#[embassy_executor::task]
pub async fn sensor_task(
    timer: Timer<'static, TIMER1>,
    counter: Timer<'static, TIMER2>,
    drdy: InputChannel<'static>,
    mut bus: Bus,
) {
    let period = Config::FEATHER.conversion_ticks();
    loop {
        let mut acc = match Accelerometer::detect(bus) {
            Ok(a) => a,
            Err((b, e)) => {
                warn!("accelerometer: {}", e);
                bus = b;
                let bus_fault = matches!(e, Error::Bus(_));
                send(Event::Sensor(status_of(e), None));
                if bus_fault {
                    bus = clear(bus);
                }
                Delay::after_secs(1).await;
                continue;
            }
        };
        let chip = acc.chip();
        let latched = chip == Chip::Lsm6ds33;
        info!("accelerometer {} at {:#x}", chip, acc.address());
        send(Event::Sensor(SensorStatus::Ok, Some(chip)));
        // A latched data-ready line stays high until the outputs are read: read once so
        // that the first edge comes.
        let _ = acc.read_counts();
        let mut seen = counter.cc(0).capture();
        let mut n: u32 = 0;
        let mut quiet = Duration::from_ticks(0);
        let mut stalled = false;
        let failure = loop {
            let edges = counter.cc(0).capture();
            if edges == seen {
                if with_timeout(LOOK_EVERY, drdy.wait()).await.is_err() {
                    quiet += LOOK_EVERY;
                    if quiet >= DRDY_TIMEOUT {
                        quiet = Duration::from_ticks(0);
                        if !stalled {
                            stalled = true;
                            send(Event::Sensor(SensorStatus::NoDataReady, Some(chip)));
                        }
                        send(Event::Poll(timer.cc(1).capture()));
                    }
                }
                continue;
            }
            quiet = Duration::from_ticks(0);
            if stalled {
                stalled = false;
                send(Event::Sensor(SensorStatus::Ok, Some(chip)));
            }
            let capture = timer.cc(0).read();
            let read_start = timer.cc(1).capture();
            let counts = match acc.read_counts() {
                Ok(c) => c,
                Err(e) => break e,
            };
            let read = Read {
                capture,
                capture_after: timer.cc(0).read(),
                read_start,
                edges,
                edges_after: counter.cc(0).capture(),
                counts,
                latched,
            };
            // Edges during the read are handled next time round.
            seen = edges;
            send(Event::Sample(pair(&read, period)));
            n = n.wrapping_add(1);
            if n % TEMPERATURE_EVERY == 0 {
                match acc.read_temperature_centi_c() {
                    Ok(t) => send(Event::Temperature(t)),
                    Err(e) => break e,
                }
            }
        };
        warn!("accelerometer failed: {}", failure);
        let bus_fault = matches!(failure, Error::Bus(_));
        send(Event::Sensor(status_of(failure), Some(chip)));
        bus = acc.release();
        if bus_fault {
            bus = clear(bus);
        }
        Delay::after_millis(200).await;
    }
}

/// Clear a bus that failed (a transfer timed out or was not acknowledged): a sensor may hold
/// SDA low in the middle of a byte.
fn clear(bus: Bus) -> Bus {
    let (bus, found) = bus.clear();
    match found {
        Recovery::WasFree | Recovery::Freed { .. } => info!("I2C bus clear: {}", found),
        Recovery::SdaStuck | Recovery::SclStuck => warn!("I2C bus clear: {}", found),
    }
    bus
}

/// Chip code for the device info.
pub fn chip_code(c: Option<Chip>) -> rotacal_shared::packet::Chip {
    match c {
        None => rotacal_shared::packet::Chip::None,
        Some(Chip::Lsm6ds33) => rotacal_shared::packet::Chip::Lsm6ds33,
        Some(Chip::Lsm6ds3trc) => rotacal_shared::packet::Chip::Lsm6ds3trc,
    }
}
