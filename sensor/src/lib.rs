//! The Feather nRF52840 Sense's accelerometer, either chip: the LSM6DS33 (WHO_AM_I 0x69,
//! older boards), set up through the `lsm6ds33` crate, or the LSM6DS3TR-C (0x6A, newer
//! boards), set up by register writes. Both then run at 104 Hz, ±2 g, with their
//! anti-alias filter, data-ready routed to INT1, and are read as raw counts.
//!
//! Why not the `lsm6ds33` crate throughout: its `new` accepts only WHO_AM_I 0x69, it
//! reads acceleration only as f32 m/s² (no raw counts), and it cannot route data-ready to
//! INT1. It is used for what it can do: detecting and configuring the LSM6DS33.
#![no_std]

pub mod types;

pub use types::{Chip, Error};

use embedded_hal::blocking::i2c::{Write, WriteRead};
use types::*;

/// A detected and configured accelerometer.
#[derive(Debug)]
pub struct Accelerometer<I2C> {
    i2c: I2C,
    addr: u8,
    chip: Chip,
}

impl<I2C, E> Accelerometer<I2C>
where
    I2C: Write<Error = E> + WriteRead<Error = E>,
{
    /// Find the chip at 0x6A or 0x6B and configure it. On failure the bus is handed back
    /// with the reason, so the caller can report it and try again later.
    pub fn detect(mut i2c: I2C) -> Result<Self, (I2C, Error<E>)> {
        let mut answered = None;
        for addr in ADDRESSES {
            match lsm6ds33::Lsm6ds33::new(i2c, addr) {
                Ok(dev) => return Self::setup_lsm6ds33(dev, addr),
                Err((bus, lsm6ds33::Error::ChipDetectFailed)) => {
                    i2c = bus;
                    let mut who = [0u8];
                    match i2c.write_read(addr, &[reg::WHO_AM_I], &mut who) {
                        Ok(()) if who == [WHO_LSM6DS3TRC] => {
                            return Self::setup_lsm6ds3trc(i2c, addr);
                        }
                        Ok(()) => answered = Some(who[0]),
                        Err(e) => return Err((i2c, Error::Bus(e))),
                    }
                }
                // No acknowledge at this address (or a failing bus): try the next one.
                Err((bus, _)) => i2c = bus,
            }
        }
        let err = match answered {
            Some(who) => Error::UnknownChip(who),
            None => Error::Absent,
        };
        Err((i2c, err))
    }

    fn setup_lsm6ds33(mut dev: lsm6ds33::Lsm6ds33<I2C>, addr: u8) -> Result<Self, (I2C, Error<E>)> {
        use lsm6ds33::{AccelerometerBandwidth, AccelerometerOutput, AccelerometerScale};
        let configured = dev
            .set_accelerometer_output(AccelerometerOutput::Rate104)
            .and_then(|()| dev.set_accelerometer_scale(AccelerometerScale::G02))
            .and_then(|()| dev.set_accelerometer_bandwidth(AccelerometerBandwidth::Freq50));
        let i2c = dev.release();
        let me = Accelerometer {
            i2c,
            addr,
            chip: Chip::Lsm6ds33,
        };
        match configured {
            Ok(()) => {}
            Err(lsm6ds33::Error::CommunicationError(e)) => return Err((me.i2c, Error::Bus(e))),
            Err(_) => return Err((me.i2c, Error::UnknownChip(WHO_LSM6DS33))),
        }
        // The crate leaves the rest: block data update, the 50 Hz anti-alias bandwidth
        // it set, and data-ready on INT1 (latched on this chip; reading clears it).
        me.write_all(&[
            (reg::CTRL3_C, CTRL3_C_BDU_IF_INC),
            (reg::CTRL4_C, CTRL4_C_XL_BW_SCAL_ODR),
            (reg::INT1_CTRL, INT1_DRDY_XL),
        ])
    }

    fn write_all(mut self, steps: &[(u8, u8)]) -> Result<Self, (I2C, Error<E>)> {
        for (r, v) in steps {
            if let Err(e) = self.write(*r, *v) {
                return Err((self.i2c, e));
            }
        }
        Ok(self)
    }

    fn setup_lsm6ds3trc(i2c: I2C, addr: u8) -> Result<Self, (I2C, Error<E>)> {
        let me = Accelerometer {
            i2c,
            addr,
            chip: Chip::Lsm6ds3trc,
        };
        me.write_all(&[
            (reg::CTRL3_C, CTRL3_C_BDU_IF_INC),
            (reg::CTRL1_XL, CTRL1_XL_TRC_104HZ_2G),
            (reg::DRDY_PULSE_CFG, DRDY_PULSED),
            (reg::INT1_CTRL, INT1_DRDY_XL),
        ])
    }

    fn write(&mut self, register: u8, value: u8) -> Result<(), Error<E>> {
        self.i2c
            .write(self.addr, &[register, value])
            .map_err(Error::Bus)
    }

    /// The chip.
    pub fn chip(&self) -> Chip {
        self.chip
    }

    /// Its I²C address.
    pub fn address(&self) -> u8 {
        self.addr
    }

    /// The latest sample: raw counts u, v, w (0.061 mg per count at ±2 g).
    pub fn read_counts(&mut self) -> Result<[i16; 3], Error<E>> {
        let mut b = [0u8; 6];
        self.i2c
            .write_read(self.addr, &[reg::OUTX_L_XL], &mut b)
            .map_err(Error::Bus)?;
        let [x0, x1, y0, y1, z0, z1] = b;
        Ok([
            i16::from_le_bytes([x0, x1]),
            i16::from_le_bytes([y0, y1]),
            i16::from_le_bytes([z0, z1]),
        ])
    }

    /// The die temperature, hundredths of °C.
    pub fn read_temperature_centi_c(&mut self) -> Result<i16, Error<E>> {
        let mut b = [0u8; 2];
        self.i2c
            .write_read(self.addr, &[reg::OUT_TEMP_L], &mut b)
            .map_err(Error::Bus)?;
        let raw = i32::from(i16::from_le_bytes(b));
        let centi = 2500 + raw * 100 / self.chip.temperature_lsb_per_c();
        Ok(i16::try_from(centi).unwrap_or(if centi > 0 { i16::MAX } else { i16::MIN }))
    }

    /// Hand the bus back.
    pub fn release(self) -> I2C {
        self.i2c
    }
}
