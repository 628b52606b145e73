//! The GATT service (docs/protocol.md) and the connection loop: notifications out of the
//! logic task's queues, commands into it.
// The gatt_service macro names its event variants after the characteristics.
#![allow(clippy::enum_variant_names)]

use crate::events::{set_link_mtu, Encoded, Event, EVENTS, RESULTS, STREAM};
use crate::logic::INFO;
use defmt::{info, warn};
use embassy_futures::select::{select, select3, Either, Either3};
use embassy_time::{Duration, Instant, Timer};
use heapless::Vec;
use nrf_softdevice::ble::advertisement_builder::{
    Flag, LegacyAdvertisementBuilder, LegacyAdvertisementPayload,
};
use nrf_softdevice::ble::gatt_server::{self, NotifyValueError};
use nrf_softdevice::ble::{peripheral, Connection};
use nrf_softdevice::{RawError, Softdevice};
use rotacal_shared::device::route::{self, MAX_MTU};
use rotacal_shared::packet::Packet;

/// GAP name, also in the advertisement.
pub const DEVICE_NAME: &str = "rotacal";

/// Largest ATT MTU the SoftDevice grants: one notification then carries 244 bytes, a
/// batch of seven averaged samples 228 (protocol version 3, its CRC included).
pub const ATT_MTU: u16 = MAX_MTU;

/// How long a packet too long for the link waits for the central's MTU exchange (which
/// BlueZ and CoreBluetooth start as they connect) before it is dropped.
const MTU_WAIT: Duration = Duration::from_secs(1);

/// The rotacal service and its characteristics.
#[nrf_softdevice::gatt_service(uuid = "7f1e0001-52a1-4b8e-9c3d-5ad1c0ca1e00")]
pub struct RotacalService {
    /// Samples and temperatures.
    #[characteristic(uuid = "7f1e0002-52a1-4b8e-9c3d-5ad1c0ca1e00", notify)]
    stream: Vec<u8, 244>,
    /// Commands (the longest is 10 bytes).
    #[characteristic(uuid = "7f1e0003-52a1-4b8e-9c3d-5ad1c0ca1e00", write)]
    control: Vec<u8, 16>,
    /// Fit reports, the quick-look, status.
    #[characteristic(uuid = "7f1e0004-52a1-4b8e-9c3d-5ad1c0ca1e00", read, notify)]
    results: Vec<u8, 244>,
    /// Chip, firmware version, clock source.
    #[characteristic(uuid = "7f1e0005-52a1-4b8e-9c3d-5ad1c0ca1e00", read)]
    info: Vec<u8, 32>,
}

/// The GATT server.
#[nrf_softdevice::gatt_server]
pub struct Server {
    rotacal: RotacalService,
}

static ADV_DATA: LegacyAdvertisementPayload = LegacyAdvertisementBuilder::new()
    .flags(&[Flag::GeneralDiscovery, Flag::LE_Only])
    .full_name(DEVICE_NAME)
    .build();
static SCAN_DATA: [u8; 0] = [];

/// Which characteristic a packet from the logic task goes out on.
#[derive(Clone, Copy)]
enum Out {
    Stream,
    Results,
}

/// How a notification ended.
enum Sent {
    /// The SoftDevice took it, or it was dropped for good.
    Done,
    /// The link is gone: the packet is kept for the next one.
    LinkGone,
}

/// Notify `v` on `ch`. Waits while the SoftDevice's queue is full and while the central
/// has not yet subscribed on this link (after a reconnection its first writes are the
/// CCCDs), so that what was queued through an outage is not thrown away; a packet longer
/// than the link's MTU allows waits up to [`MTU_WAIT`] for the MTU exchange, then is
/// dropped (the device logic sizes the next batches to the MTU; the host fetches the
/// samples again).
async fn notify(server: &Server, conn: &Connection, ch: Out, v: &Encoded) -> Sent {
    let since = Instant::now();
    loop {
        if v.len() > route::payload(conn.att_mtu()) {
            if since.elapsed() > MTU_WAIT {
                warn!(
                    "{} bytes do not fit MTU {}: dropped",
                    v.len(),
                    conn.att_mtu()
                );
                return Sent::Done;
            }
            Timer::after_millis(5).await;
            continue;
        }
        let r = match ch {
            Out::Stream => server.rotacal.stream_notify(conn, v),
            Out::Results => server.rotacal.results_notify(conn, v),
        };
        match r {
            Ok(()) => {
                let mtu = conn.att_mtu();
                if mtu > raw_default_mtu() {
                    set_link_mtu(mtu);
                }
                return Sent::Done;
            }
            // Queue full; or notifications not enabled (yet) on this link.
            Err(NotifyValueError::Raw(
                RawError::Resources | RawError::InvalidState | RawError::BleGattsSysAttrMissing,
            )) => Timer::after_millis(5).await,
            Err(NotifyValueError::Disconnected) => return Sent::LinkGone,
            Err(e) => {
                warn!("notify: {}", e);
                return Sent::Done;
            }
        }
    }
}

/// BLE's default ATT MTU, which a connection has until the central asks for more.
const fn raw_default_mtu() -> u16 {
    nrf_softdevice::raw::BLE_GATT_ATT_MTU_DEFAULT as u16
}

fn on_control(v: &[u8]) {
    match Packet::decode(v) {
        Ok(Packet::Command(c)) => {
            if EVENTS.try_send(Event::Command(c)).is_err() {
                warn!("command dropped: event queue full");
            }
        }
        Ok(other) => warn!("control: not a command: {}", other),
        Err(e) => warn!("control: {}", e),
    }
}

fn set_info(server: &Server, v: &Encoded) {
    if let Ok(v) = Vec::from_slice(v) {
        if server.rotacal.info_set(&v).is_err() {
            warn!("cannot set the info value");
        }
    }
}

/// Serve one connection until it ends. `held` is a packet taken from a queue and not yet
/// sent: it survives the link (the pump future is dropped mid-send when the link ends).
async fn serve(server: &Server, conn: &Connection, held: &mut Option<(Out, Encoded)>) {
    let gatt = gatt_server::run(conn, server, |e| match e {
        ServerEvent::Rotacal(RotacalServiceEvent::ControlWrite(v)) => {
            // By its first command the central has exchanged MTUs if it ever will: the
            // device logic sizes batches to this value, and refuses work below MIN_MTU.
            set_link_mtu(conn.att_mtu());
            on_control(&v)
        }
        ServerEvent::Rotacal(_) => {}
    });
    let pump = async {
        loop {
            if held.is_none() {
                *held = match select3(STREAM.receive(), RESULTS.receive(), INFO.wait()).await {
                    Either3::First(v) => Some((Out::Stream, v)),
                    Either3::Second(v) => {
                        // Kept as the characteristic's value too, for reads.
                        let _ = server.rotacal.results_set(&v);
                        Some((Out::Results, v))
                    }
                    Either3::Third(v) => {
                        set_info(server, &v);
                        None
                    }
                };
            }
            let Some((ch, v)) = held.as_ref() else {
                continue;
            };
            match notify(server, conn, *ch, v).await {
                Sent::Done => *held = None,
                Sent::LinkGone => return,
            }
        }
    };
    match select(gatt, pump).await {
        Either::First(e) => info!("disconnected: {}", e),
        Either::Second(()) => {}
    }
}

/// Advertise, serve, repeat.
pub async fn run(sd: &'static Softdevice, server: &Server) -> ! {
    let config = peripheral::Config::default();
    let mut held = None;
    loop {
        if let Some(v) = INFO.try_take() {
            set_info(server, &v);
        }
        let adv = peripheral::ConnectableAdvertisement::ScannableUndirected {
            adv_data: &ADV_DATA,
            scan_data: &SCAN_DATA,
        };
        match peripheral::advertise_connectable(sd, adv, &config).await {
            Ok(conn) => {
                info!("connected");
                serve(server, &conn, &mut held).await;
            }
            Err(e) => {
                warn!("advertising failed: {}", e);
                Timer::after_secs(1).await;
            }
        }
    }
}
