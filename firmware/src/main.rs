//! rotacal firmware for the Adafruit Feather nRF52840 Sense.
//!
//! For now: enable the S140 7.3.0 SoftDevice and advertise connectably as "rotacal",
//! serving each connection until the central disconnects. Sampling and streaming come later;
//! their logic belongs in `rotacal-shared`, this crate stays the thin nRF glue.

#![no_std]
#![no_main]

use defmt::{error, info, warn};
use embassy_executor::Spawner;
use embassy_nrf::interrupt::Priority;
use embassy_time::Timer;
use nrf_softdevice::ble::advertisement_builder::{
    Flag, LegacyAdvertisementBuilder, LegacyAdvertisementPayload,
};
use nrf_softdevice::ble::gatt_server::{self, WriteOp};
use nrf_softdevice::ble::{peripheral, Connection};
use nrf_softdevice::{raw, Softdevice};
use {defmt_rtt as _, panic_probe as _};

/// GAP device name, also sent as the complete local name in the advertisement.
const DEVICE_NAME: &str = "rotacal";

/// Largest ATT MTU we grant: 247 lets one notification carry 244 bytes of payload,
/// which fits a 251-byte LL data PDU (the SoftDevice negotiates data length on request).
const ATT_MTU: u16 = 247;

/// Advertising data: flags + complete local name. Built at compile time, so an oversize
/// payload is a build error, not a runtime panic. `static` because the SoftDevice reads it
/// for as long as advertising runs.
static ADV_DATA: LegacyAdvertisementPayload = LegacyAdvertisementBuilder::new()
    .flags(&[Flag::GeneralDiscovery, Flag::LE_Only])
    .full_name(DEVICE_NAME)
    .build();

/// Scan response: empty for now (the name already fits in the advertising data).
static SCAN_DATA: [u8; 0] = [];

/// A GATT server with no services of its own yet (the SoftDevice still serves the
/// Generic Access and Generic Attribute services). Running it on a connection answers
/// the SoftDevice's GATTS events (e.g. missing system attributes) and ends on disconnect.
struct NoServices;

impl gatt_server::Server for NoServices {
    type Event = ();

    fn on_write(
        &self,
        _conn: &Connection,
        handle: u16,
        _op: WriteOp,
        _offset: usize,
        _data: &[u8],
    ) -> Option<Self::Event> {
        warn!("write to unknown handle {}", handle);
        None
    }
}

/// Runs the SoftDevice event loop; without it no BLE operation ever completes.
#[embassy_executor::task]
async fn softdevice_task(sd: &'static Softdevice) -> ! {
    sd.run().await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    info!("rotacal firmware starting");

    // Priorities 0, 1 and 4 belong to the SoftDevice; our interrupts must use 2, 3 or lower.
    let mut nrf_config = embassy_nrf::config::Config::default();
    nrf_config.gpiote_interrupt_priority = Priority::P2;
    nrf_config.time_interrupt_priority = Priority::P2;
    let _peripherals = embassy_nrf::init(nrf_config);

    let sd_config = nrf_softdevice::Config {
        // The board has no 32.768 kHz crystal: use the LF RC oscillator, recalibrated
        // every 16 × 0.25 s = 4 s, and at least every 2 × 4 s = 8 s even if the temperature
        // has not changed; ±500 ppm is what the BLE timing has to allow for.
        clock: Some(raw::nrf_clock_lf_cfg_t {
            source: raw::NRF_CLOCK_LF_SRC_RC as u8,
            rc_ctiv: 16,
            rc_temp_ctiv: 2,
            accuracy: raw::NRF_CLOCK_LF_ACCURACY_500_PPM as u8,
        }),
        // One central (the host) at a time. Event length 24 × 1.25 ms = 30 ms gives room
        // for several packets per connection event when streaming.
        conn_gap: Some(raw::ble_gap_conn_cfg_t {
            conn_count: 1,
            event_length: 24,
        }),
        conn_gatt: Some(raw::ble_gatt_conn_cfg_t { att_mtu: ATT_MTU }),
        // Notifications are queued here; a full queue makes notify fail, so leave headroom.
        conn_gatts: Some(raw::ble_gatts_conn_cfg_t {
            hvn_tx_queue_size: 16,
        }),
        // Attribute table for our services (the default is 1408 bytes); plenty for a few
        // characteristics. Raise it if service registration fails with NoMem.
        gatts_attr_tab_size: Some(raw::ble_gatts_cfg_attr_tab_size_t {
            attr_tab_size: 4096,
        }),
        // Peripheral only: one advertising set, one peripheral link, no central role.
        gap_role_count: Some(raw::ble_gap_cfg_role_count_t {
            adv_set_count: 1,
            periph_role_count: 1,
            central_role_count: 0,
            central_sec_count: 0,
            _bitfield_1: raw::ble_gap_cfg_role_count_t::new_bitfield_1(0),
        }),
        // The name lives in the SoftDevice (VLOC_STACK copies it there). Write permission
        // sm=0, lv=0 means "no access": a central cannot rename the device.
        gap_device_name: Some(raw::ble_gap_cfg_device_name_t {
            p_value: DEVICE_NAME.as_ptr().cast_mut(),
            current_len: DEVICE_NAME.len() as u16,
            max_len: DEVICE_NAME.len() as u16,
            write_perm: raw::ble_gap_conn_sec_mode_t {
                _bitfield_1: raw::ble_gap_conn_sec_mode_t::new_bitfield_1(0, 0),
            },
            _bitfield_1: raw::ble_gap_cfg_device_name_t::new_bitfield_1(
                raw::BLE_GATTS_VLOC_STACK as u8,
            ),
        }),
        ..Default::default()
    };

    // Panics (after logging the RAM start it needs) if memory.x gives the SoftDevice too
    // little RAM: a build configuration error, not something to recover from at run time.
    let sd: &'static Softdevice = Softdevice::enable(&sd_config);

    if let Err(e) = spawner.spawn(softdevice_task(sd)) {
        // Only possible if the task were spawned twice. Without the event loop advertising
        // would never complete, so stop here (the executor idles) rather than hang in it.
        error!("cannot spawn the SoftDevice task: {}", e);
        return;
    }

    let server = NoServices;
    let adv_config = peripheral::Config::default(); // 250 ms interval, 0 dBm, no timeout
    loop {
        let adv = peripheral::ConnectableAdvertisement::ScannableUndirected {
            adv_data: &ADV_DATA,
            scan_data: &SCAN_DATA,
        };
        let conn = match peripheral::advertise_connectable(sd, adv, &adv_config).await {
            Ok(conn) => conn,
            Err(e) => {
                // E.g. a SoftDevice error; back off instead of spinning, then retry.
                warn!("advertising failed: {}", e);
                Timer::after_secs(1).await;
                continue;
            }
        };
        info!("connected");

        // Serve the connection until the central goes away, then advertise again.
        gatt_server::run(&conn, &server, |()| {}).await;
        info!("disconnected");
    }
}
