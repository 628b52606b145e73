//! The I²C bus with a timeout on every transfer: a sensor holding the bus (SDA low after a
//! brown-out, a loose wire) ends in a bus error that the sensor task reports and recovers
//! from (it detects the sensor again), instead of a wait that never returns.

use embassy_nrf::peripherals::TWISPI0;
use embassy_nrf::twim::{Error, Twim};
use embassy_time::Duration;
use embedded_hal::blocking::i2c::{Write, WriteRead};

/// Longest transfer: the sensor's 6-byte read takes about 0.3 ms at 390 kHz.
const TIMEOUT: Duration = Duration::from_millis(5);

/// See the module documentation.
pub struct Bus(pub Twim<'static, TWISPI0>);

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
