//! The logic task: owns the hardware-independent [`Device`] (rotacal-shared), feeds it the
//! sensor's and the host's events, and routes what it sends to the BLE characteristics.

use crate::events::{link_mtu, take_overflows, Encoded, Event, EVENTS, RESULTS, STREAM};
use crate::sampling::chip_code;
use defmt::{info, warn};
use embassy_nrf::gpio::Output;
use embassy_nrf::wdt::WatchdogHandle;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use rotacal_shared::device::route::{Characteristic, Room};
use rotacal_shared::device::{Config, Device, RING};
use rotacal_shared::packet::{ClockSource, Packet, RunState};

/// The latest device-info value, for the BLE side to publish.
pub static INFO: Signal<CriticalSectionRawMutex, Encoded> = Signal::new();

fn version() -> [u8; 3] {
    let p = |s: &str| s.parse::<u8>().unwrap_or(0);
    [
        p(env!("CARGO_PKG_VERSION_MAJOR")),
        p(env!("CARGO_PKG_VERSION_MINOR")),
        p(env!("CARGO_PKG_VERSION_PATCH")),
    ]
}

fn encode(p: &Packet) -> Option<Encoded> {
    let mut buf = [0u8; rotacal_shared::packet::MAX_PACKET];
    let n = p.encode(&mut buf).ok()?;
    Encoded::from_slice(buf.get(..n)?).ok()
}

/// Each packet to its characteristic's queue, as rotacal-shared routes it
/// ([`Characteristic::of`]). A full queue drops a live packet: samples can be fetched
/// again from the ring (Backfill). Replays and status replies are never offered beyond
/// the room ([`Device::pump`]).
fn route(p: Packet) {
    let Some(v) = encode(&p) else {
        warn!("cannot encode {}", p);
        return;
    };
    let sent = match Characteristic::of(&p) {
        Some(Characteristic::Stream) => STREAM.try_send(v).is_ok(),
        Some(Characteristic::Results) => RESULTS.try_send(v).is_ok(),
        Some(Characteristic::Info) => {
            INFO.signal(v);
            true
        }
        None => true,
    };
    if !sent {
        warn!("BLE queue full: packet dropped");
    }
}

/// The queues' free places, for [`Device::pump`].
fn room() -> Room {
    Room {
        stream: STREAM.free_capacity(),
        results: RESULTS.free_capacity(),
    }
}

/// The device's state, 12 KiB with its ring: a static of its own rather than part of
/// the task's future, which lives in the executor's small arena. `clock` is what the
/// timestamps run on, as the device info reports it.
pub fn device(clock: ClockSource) -> Option<&'static mut Device<RING>> {
    let cfg = Config {
        clock_source: clock,
        ..Config::FEATHER
    };
    cortex_m::singleton!(: Device<RING> = Device::new(cfg))
}

/// See the module documentation. `led` (red, P1.09) lights when x, y and z are done. The
/// watchdog is petted at every event: the sensor task sends one at least every second
/// while the executor runs.
#[embassy_executor::task]
pub async fn logic_task(
    dev: &'static mut Device<RING>,
    mut led: Output<'static>,
    mut watchdog: Option<WatchdogHandle>,
) {
    let mut chip = None;
    let mut out = route;
    loop {
        let ev = EVENTS.receive().await;
        if let Some(w) = &mut watchdog {
            w.pet();
        }
        // Batches are sized to the link the BLE task reports (a no-op when unchanged).
        dev.set_link_mtu(link_mtu(), &mut out);
        let lost = take_overflows();
        if lost > 0 {
            dev.on_lost(lost);
        }
        match ev {
            Event::Sample(c) => {
                dev.on_conversion(&c, &mut out);
                dev.poll(c.capture, &mut out);
            }
            Event::Temperature(t) => dev.on_temperature(t, &mut out),
            Event::Sensor(status, c) => {
                if c.is_some() {
                    chip = c;
                }
                dev.on_sensor_status(status, &mut out);
                if let Some(v) = encode(&Packet::Info(dev.info(chip_code(chip), version()))) {
                    INFO.signal(v);
                }
            }
            Event::Command(c) => {
                info!("command {}", c);
                let before = dev.status().state;
                dev.command(c, &mut out);
                let now = dev.status().state;
                if now == RunState::Complete && before != RunState::Complete {
                    if let Some(q) = dev.quick_look() {
                        info!(
                            "quick-look: s = {} counts/(m/s²), φ = {} deg",
                            q.sensitivity, q.angle_deg
                        );
                    }
                    led.set_high();
                } else if now != RunState::Complete {
                    led.set_low();
                }
            }
            Event::Poll(now) => dev.poll(u64::from(now), &mut out),
        }
        // A backfill and a status reply go as the BLE side drains the queues: every event
        // (a conversion at 104 Hz, a poll every 100 ms) offers them the free places.
        dev.pump(room(), &mut out);
    }
}
