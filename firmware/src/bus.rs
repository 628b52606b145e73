//! The I²C bus with a timeout on every transfer, and a bus clear: a sensor holding the bus
//! (SDA low after a reset mid-transfer, a brown-out, a loose wire) ends in a bus error that
//! the sensor task reports, then clears the bus (`rotacal_shared::device::bus_recovery`:
//! up to nine clocks and a STOP, on the pins as open-drain GPIOs) and detects the sensor
//! again, instead of a wait that never returns.

use crate::Irqs;
use embassy_nrf::gpio::{Flex, OutputDrive, Pull};
use embassy_nrf::peripherals::{P0_11, P0_12, TWISPI0};
use embassy_nrf::twim::{self, Error, Twim};
use embassy_time::{block_for, Duration};
use embedded_hal::blocking::i2c::{Write, WriteRead};
use rotacal_shared::device::bus_recovery::{recover, Lines, Recovery};

/// Longest transfer: the sensor's 6-byte read takes about 0.3 ms at 390 kHz.
const TIMEOUT: Duration = Duration::from_millis(5);

/// See the module documentation: the TWIM on SDA P0.12, SCL P0.11 (the Feather's I²C).
pub struct Bus(Twim<'static, TWISPI0>);

impl Bus {
    /// The TWIM at 390 kHz on the board's I²C pins.
    pub fn new(twim: TWISPI0, sda: P0_12, scl: P0_11) -> Self {
        let mut config = twim::Config::default();
        config.frequency = twim::Frequency::K400;
        let bus = Bus(Twim::new(twim, Irqs, sda, scl, config));
        // nRF52840 erratum 219: at 400 kHz the TWIM's SCL low time is below the I²C minimum
        // (1.3 µs); Nordic's workaround is 390 kHz, FREQUENCY = 0x06200000, which
        // embassy-nrf 0.2's Frequency does not offer. Written after Twim::new set 400 kHz
        // and before any transfer.
        // SAFETY: TWIM0 is this bus's (TWISPI0, owned) and idle; FREQUENCY takes any value.
        unsafe {
            (*embassy_nrf::pac::TWIM0::ptr())
                .frequency
                .write(|w| w.frequency().bits(0x0620_0000));
        }
        bus
    }

    /// Clear the bus and make the TWIM afresh: what the clear found.
    pub fn clear(self) -> (Self, Recovery) {
        // Dropping the TWIM disables it and gives its pins back as GPIOs.
        drop(self);
        // SAFETY: the TWIM that owned these peripherals was dropped above, and nothing else
        // in the firmware uses them; each is stolen once for the clear and once for the new
        // TWIM, after the clear's pins are dropped.
        let (sda, scl) = unsafe { (P0_12::steal(), P0_11::steal()) };
        let mut lines = OpenDrain {
            sda: Flex::new(sda),
            scl: Flex::new(scl),
        };
        for pin in [&mut lines.sda, &mut lines.scl] {
            pin.set_high();
            pin.set_as_input_output(Pull::Up, OutputDrive::Standard0Disconnect1);
        }
        let found = recover(&mut lines);
        drop(lines);
        // SAFETY: as above; the clear's Flex pins are dropped (disconnected).
        let bus = unsafe { Bus::new(TWISPI0::steal(), P0_12::steal(), P0_11::steal()) };
        (bus, found)
    }
}

/// The two pins as open-drain GPIOs: high releases the line to its pull-up.
struct OpenDrain {
    sda: Flex<'static>,
    scl: Flex<'static>,
}

impl Lines for OpenDrain {
    fn set_scl(&mut self, high: bool) {
        if high {
            self.scl.set_high();
        } else {
            self.scl.set_low();
        }
    }

    fn set_sda(&mut self, high: bool) {
        if high {
            self.sda.set_high();
        } else {
            self.sda.set_low();
        }
    }

    fn sda_is_high(&mut self) -> bool {
        self.sda.is_high()
    }

    fn scl_is_high(&mut self) -> bool {
        self.scl.is_high()
    }

    fn half_period(&mut self) {
        // 100 kHz: every I²C device takes it.
        block_for(Duration::from_micros(5));
    }
}

impl Write for Bus {
    type Error = Error;
    fn write(&mut self, address: u8, bytes: &[u8]) -> Result<(), Error> {
        self.0.blocking_write_timeout(address, bytes, TIMEOUT)
    }
}

impl WriteRead for Bus {
    type Error = Error;
    fn write_read(&mut self, address: u8, bytes: &[u8], buffer: &mut [u8]) -> Result<(), Error> {
        self.0
            .blocking_write_read_timeout(address, bytes, buffer, TIMEOUT)
    }
}
