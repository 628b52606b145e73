//! Registers, chips and errors.

/// Which chip answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Chip {
    /// LSM6DS33, WHO_AM_I 0x69 (older boards).
    Lsm6ds33,
    /// LSM6DS3TR-C, WHO_AM_I 0x6A (newer boards).
    Lsm6ds3trc,
}

impl Chip {
    /// Temperature output, LSB per °C (0 LSB = 25 °C): 16 on the LSM6DS33, 256 on the
    /// LSM6DS3TR-C (ST's drivers for each).
    pub const fn temperature_lsb_per_c(self) -> i32 {
        match self {
            Chip::Lsm6ds33 => 16,
            Chip::Lsm6ds3trc => 256,
        }
    }
}

/// A driver error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<CommE> {
    /// An I²C transfer failed.
    Bus(CommE),
    /// No chip answered at 0x6A or 0x6B.
    Absent,
    /// A chip answered with this WHO_AM_I, neither 0x69 nor 0x6A.
    UnknownChip(u8),
}

/// I²C addresses: SA0 low (the Feather's wiring), then high.
pub const ADDRESSES: [u8; 2] = [0x6A, 0x6B];

/// Register addresses (the same on both chips unless noted).
pub mod reg {
    /// DRDY_PULSE_CFG on the LSM6DS3TR-C (bit 7: pulsed data-ready). On the LSM6DS33 this
    /// address is ORIENT_CFG_G and has no such bit.
    pub const DRDY_PULSE_CFG: u8 = 0x0B;
    /// INT1 routing.
    pub const INT1_CTRL: u8 = 0x0D;
    /// Identity.
    pub const WHO_AM_I: u8 = 0x0F;
    /// Accelerometer rate, range and filter.
    pub const CTRL1_XL: u8 = 0x10;
    /// BDU, IF_INC.
    pub const CTRL3_C: u8 = 0x12;
    /// On the LSM6DS33, bit 7 XL_BW_SCAL_ODR: use the BW_XL bits of CTRL1_XL (on the
    /// LSM6DS3TR-C bit 7 means something else, so it is not written there).
    pub const CTRL4_C: u8 = 0x13;
    /// Temperature, i16 little-endian.
    pub const OUT_TEMP_L: u8 = 0x20;
    /// Acceleration X, Y, Z, i16 little-endian.
    pub const OUTX_L_XL: u8 = 0x28;
}

/// WHO_AM_I of the LSM6DS33.
pub const WHO_LSM6DS33: u8 = 0x69;
/// WHO_AM_I of the LSM6DS3TR-C.
pub const WHO_LSM6DS3TRC: u8 = 0x6A;

/// CTRL3_C: block data update (the three axes of one sample, never mixed) and address
/// auto-increment.
pub const CTRL3_C_BDU_IF_INC: u8 = 0x44;
/// CTRL4_C on the LSM6DS33: the anti-alias bandwidth from CTRL1_XL's BW_XL bits (50 Hz
/// here) rather than chosen from the rate.
pub const CTRL4_C_XL_BW_SCAL_ODR: u8 = 0x80;
/// INT1_CTRL: accelerometer data-ready on INT1 (P1.11 on the Feather).
pub const INT1_DRDY_XL: u8 = 0x01;
/// DRDY_PULSE_CFG: pulsed data-ready (LSM6DS3TR-C), so every conversion gives an edge.
pub const DRDY_PULSED: u8 = 0x80;
/// CTRL1_XL on the LSM6DS3TR-C: 104 Hz, ±2 g, LPF1 at ODR/2 (the anti-alias filter of
/// the digital chain), analog bandwidth 1.5 kHz.
pub const CTRL1_XL_TRC_104HZ_2G: u8 = 0x40;

/// The output data rate this driver sets, mHz.
pub const ODR_MHZ: u32 = 104_000;
/// The full scale this driver sets, ±g.
pub const FULL_SCALE_G: u8 = 2;
