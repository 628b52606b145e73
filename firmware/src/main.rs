//! rotacal firmware for the Adafruit Feather nRF52840 Sense: thin glue around
//! `rotacal_shared::device` (the logic, tested on the host and under QEMU).
//!
//! Tasks: `sampling` (data-ready edge captured by GPIOTE → PPI → TIMER1 and counted by
//! TIMER2 on the channel's fork, sample read over I²C), `logic` (the shared `Device`:
//! stream, ring, fits, quick-look), and the BLE loop in `main` (`ble`: one GATT service,
//! docs/protocol.md). Interrupts run at P2, as the
//! SoftDevice requires; the LF clock is the RC oscillator (the board has no crystal).

#![no_std]
#![no_main]

mod ble;
mod bus;
mod events;
mod logic;
mod sampling;

use defmt::{error, info, warn};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_nrf::gpio::{Input, Level, Output, OutputDrive, Pull};
use embassy_nrf::gpiote::{InputChannel, InputChannelPolarity};
use embassy_nrf::interrupt::{self, InterruptExt, Priority};
use embassy_nrf::peripherals::TWISPI0;
use embassy_nrf::ppi::Ppi;
use embassy_nrf::timer::{Frequency, Timer as HwTimer};
use embassy_nrf::wdt::{self, Watchdog};
use embassy_nrf::{bind_interrupts, twim};
use embassy_time::Timer;
use nrf_softdevice::{raw, RawError, Softdevice};
use rotacal_shared::packet::ClockSource;
#[cfg(all(feature = "panic-probe", feature = "panic-reset"))]
compile_error!("one panic handler: panic-probe (with a probe) or panic-reset (without)");
#[cfg(feature = "panic-probe")]
use panic_probe as _;
#[cfg(feature = "panic-reset")]
use panic_reset as _;

/// The watchdog's period in its 32 768 Hz ticks (rotacal-shared's `WATCHDOG_MS`, which says
/// why 4 s).
const WATCHDOG_TICKS: u32 = rotacal_shared::device::WATCHDOG_MS / 1000 * 32_768;

bind_interrupts!(struct Irqs {
    SPIM0_SPIS0_TWIM0_TWIS0_SPI0_TWI0 => twim::InterruptHandler<TWISPI0>;
});

/// Runs the SoftDevice event loop; without it no BLE operation ever completes.
#[embassy_executor::task]
async fn softdevice_task(sd: &'static Softdevice) -> ! {
    sd.run().await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    info!("rotacal firmware starting");

    // Priorities 0, 1 and 4 belong to the SoftDevice; ours use 2.
    let mut nrf_config = embassy_nrf::config::Config::default();
    nrf_config.gpiote_interrupt_priority = Priority::P2;
    nrf_config.time_interrupt_priority = Priority::P2;
    let p = embassy_nrf::init(nrf_config);

    // TIMER1 at 1 MHz, 32 bits, free-running (TIMER0 is the SoftDevice's). The data-ready
    // edge on P1.11 triggers CAPTURE[0] through PPI channel 0 (0–16 are ours). embassy-nrf
    // 0.2's task_capture() always names CAPTURE[0] whatever n is, so CC[0] it is; CC[1]
    // takes software "now" readings.
    let timer = HwTimer::new(p.TIMER1);
    timer.set_frequency(Frequency::F1MHz);
    timer.clear();
    // TIMER2 counts the edges on the channel's fork, so that a conversion that is never
    // read is still counted.
    let counter = HwTimer::new_counter(p.TIMER2);
    counter.clear();
    let drdy = InputChannel::new(
        p.GPIOTE_CH0,
        Input::new(p.P1_11, Pull::None),
        InputChannelPolarity::LoToHi,
    );
    let mut ppi = Ppi::new_one_to_two(
        p.PPI_CH0,
        drdy.event_in(),
        timer.cc(0).task_capture(),
        counter.task_count(),
    );
    ppi.enable();
    // Dropping the Ppi would unwire the channel; it must live for ever.
    core::mem::forget(ppi);
    timer.start();
    counter.start();

    // Twim::new enables its interrupt at priority 0 unless set before.
    interrupt::SPIM0_SPIS0_TWIM0_TWIS0_SPI0_TWI0.set_priority(Priority::P2);
    let bus = bus::Bus::new(p.TWISPI0, p.P0_12, p.P0_11);
    let led = Output::new(p.P1_09, Level::Low, OutputDrive::Standard);
    let mut wdt_config = wdt::Config::default();
    wdt_config.timeout_ticks = WATCHDOG_TICKS;
    wdt_config.run_during_sleep = true;
    // A debugger's halt is not a hang.
    wdt_config.run_during_debug_halt = false;
    let watchdog = match Watchdog::try_new::<1>(p.WDT, wdt_config) {
        Ok((_, [handle])) => Some(handle),
        Err(_) => {
            // Started before us (by a bootloader) with another configuration, which
            // cannot be changed until reset: it then resets the board unpetted.
            warn!("the watchdog runs with another configuration; not petting it");
            None
        }
    };

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
        conn_gatt: Some(raw::ble_gatt_conn_cfg_t {
            att_mtu: ble::ATT_MTU,
        }),
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
            p_value: ble::DEVICE_NAME.as_ptr().cast_mut(),
            current_len: ble::DEVICE_NAME.len() as u16,
            max_len: ble::DEVICE_NAME.len() as u16,
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
    let sd = Softdevice::enable(&sd_config);
    let server = match ble::Server::new(sd) {
        Ok(s) => s,
        Err(e) => {
            error!("GATT service registration failed: {}", e);
            return;
        }
    };
    let sd: &'static Softdevice = sd;
    let clock = hfxo().await;
    let Some(device) = logic::device(clock) else {
        error!("device state already taken");
        return;
    };
    let spawned = [
        spawner.spawn(softdevice_task(sd)),
        spawner.spawn(sampling::sensor_task(timer, counter, drdy, bus)),
        spawner.spawn(logic::logic_task(device, led, watchdog)),
    ];
    if spawned.iter().any(Result::is_err) {
        // Only possible if a task were spawned twice.
        error!("cannot spawn the tasks");
        return;
    }

    ble::run(sd, &server).await
}

/// TIMER1 counts HFCLK: put it on the 32 MHz crystal (±20–40 ppm) rather than the internal
/// RC, so that timestamps hold the rate. What the timestamps run on is what the device info
/// reports: the crystal only once it runs (it starts in well under a millisecond; 10 ms are
/// allowed), else the internal oscillator, which the host warns of.
async fn hfxo() -> ClockSource {
    // SAFETY: a SoftDevice call with no pointer arguments, made after it is enabled.
    if let Err(e) = RawError::convert(unsafe { raw::sd_clock_hfclk_request() }) {
        warn!("HFXO request failed: {}; timestamps run on HFINT", e);
        return ClockSource::TimerHfint;
    }
    for _ in 0..10 {
        let mut running: u32 = 0;
        // SAFETY: the SoftDevice writes one u32 through a pointer to a live local.
        let ret = unsafe { raw::sd_clock_hfclk_is_running(&mut running) };
        if RawError::convert(ret).is_ok() && running != 0 {
            return ClockSource::TimerHfxo;
        }
        Timer::after_millis(1).await;
    }
    warn!("HFXO did not start within 10 ms; timestamps run on HFINT");
    ClockSource::TimerHfint
}
