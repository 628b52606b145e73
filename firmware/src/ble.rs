//! The GATT service (docs/protocol.md) and the connection loop: notifications out of the
//! logic task's queues, commands into it.
// The gatt_service macro names its event variants after the characteristics.
#![allow(clippy::enum_variant_names)]

use crate::events::{Encoded, Event, EVENTS, RESULTS, STREAM};
use crate::logic::INFO;
use defmt::{info, warn};
use embassy_futures::select::{select, select3, Either, Either3};
use embassy_time::Timer;
use heapless::Vec;
use nrf_softdevice::ble::advertisement_builder::{
    Flag, LegacyAdvertisementBuilder, LegacyAdvertisementPayload,
};
use nrf_softdevice::ble::gatt_server::{self, NotifyValueError};
use nrf_softdevice::ble::{peripheral, Connection};
use nrf_softdevice::{RawError, Softdevice};
use rotacal_shared::packet::Packet;

/// GAP name, also in the advertisement.
pub const DEVICE_NAME: &str = "rotacal";

/// Largest ATT MTU: one notification then carries 244 bytes, the largest packet being 236.
pub const ATT_MTU: u16 = 247;

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

/// Notify, waiting while the SoftDevice's queue is full; gives up if the link is gone or
/// the host has not enabled notifications.
async fn notify(f: impl Fn() -> Result<(), NotifyValueError>) {
    loop {
        match f() {
            Ok(()) => return,
            Err(NotifyValueError::Raw(RawError::Resources)) => Timer::after_millis(5).await,
            Err(e) => {
                warn!("notify: {}", e);
                return;
            }
        }
    }
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

/// Ask for the 247-byte ATT MTU, for centrals that don't ask themselves (one sample
/// batch needs up to 236 bytes). Refused when the central already started an exchange,
/// which is fine: the SoftDevice answers that one with our maximum. Without the GATT
/// client feature the reply event is not passed up, so `att_mtu()` may not show the new
/// value; the SoftDevice still uses it.
fn request_mtu(conn: &Connection) {
    if let Some(handle) = conn.handle() {
        // SAFETY: a SoftDevice call on a live connection handle, no pointers.
        let ret =
            unsafe { nrf_softdevice::raw::sd_ble_gattc_exchange_mtu_request(handle, ATT_MTU) };
        if let Err(e) = RawError::convert(ret) {
            info!("MTU request not sent: {}", e);
        }
    }
}

/// Serve one connection until it ends.
async fn serve(server: &Server, conn: &Connection) {
    let gatt = gatt_server::run(conn, server, |e| match e {
        ServerEvent::Rotacal(RotacalServiceEvent::ControlWrite(v)) => on_control(&v),
        ServerEvent::Rotacal(_) => {}
    });
    let pump = async {
        loop {
            match select3(STREAM.receive(), RESULTS.receive(), INFO.wait()).await {
                Either3::First(v) => notify(|| server.rotacal.stream_notify(conn, &v)).await,
                Either3::Second(v) => {
                    // Kept as the characteristic's value too, for reads.
                    let _ = server.rotacal.results_set(&v);
                    notify(|| server.rotacal.results_notify(conn, &v)).await
                }
                Either3::Third(v) => set_info(server, &v),
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
                request_mtu(&conn);
                serve(server, &conn).await;
            }
            Err(e) => {
                warn!("advertising failed: {}", e);
                Timer::after_secs(1).await;
            }
        }
    }
}
