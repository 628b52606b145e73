//! The driver against a mocked I²C bus (embedded-hal-mock): the exact transfers for each
//! chip, and the failures a missing or foreign chip gives.
#![allow(clippy::unwrap_used, clippy::indexing_slicing)]

use embedded_hal_mock::i2c::{Mock, Transaction as T};
use embedded_hal_mock::MockError;
use rotacal_sensor::{Accelerometer, Chip, Error};
use std::io::ErrorKind;

const A: u8 = 0x6A;

fn nack(addr: u8, reg: u8) -> T {
    T::write_read(addr, vec![reg], vec![0]).with_error(MockError::Io(ErrorKind::Other))
}

/// The lsm6ds33 crate's read-modify-writes, then ours.
fn lsm6ds33_setup() -> Vec<T> {
    vec![
        T::write_read(A, vec![0x0F], vec![0x69]), // WHO_AM_I
        T::write_read(A, vec![0x12], vec![0x00]), // CTRL3_C: IF_INC
        T::write(A, vec![0x12, 0x04]),
        T::write_read(A, vec![0x10], vec![0x00]), // CTRL1_XL: 104 Hz
        T::write(A, vec![0x10, 0x40]),
        T::write_read(A, vec![0x10], vec![0x40]), // ±2 g
        T::write(A, vec![0x10, 0x40]),
        T::write_read(A, vec![0x10], vec![0x40]), // BW 50 Hz
        T::write(A, vec![0x10, 0x43]),
        T::write(A, vec![0x12, 0x44]), // BDU | IF_INC
        T::write(A, vec![0x13, 0x80]), // XL_BW_SCAL_ODR
        T::write(A, vec![0x0D, 0x01]), // INT1_DRDY_XL
    ]
}

#[test]
fn lsm6ds33_is_set_up_through_the_crate_and_read_raw() {
    let mut t = lsm6ds33_setup();
    t.push(T::write_read(
        A,
        vec![0x28],
        vec![0x01, 0x00, 0xFF, 0xFF, 0x00, 0x40],
    ));
    t.push(T::write_read(A, vec![0x20], vec![0x20, 0x00])); // +32 LSB = +2 °C
    let mut bus = Mock::new(&t);
    let mut acc = Accelerometer::detect(bus.clone()).unwrap();
    assert_eq!(acc.chip(), Chip::Lsm6ds33);
    assert_eq!(acc.read_counts().unwrap(), [1, -1, 16384]);
    assert_eq!(acc.read_temperature_centi_c().unwrap(), 2700);
    bus.done();
}

#[test]
fn lsm6ds3trc_is_set_up_by_registers() {
    let t = vec![
        T::write_read(A, vec![0x0F], vec![0x6A]), // the crate: not 0x69
        T::write_read(A, vec![0x0F], vec![0x6A]), // ours: the TR-C
        T::write(A, vec![0x12, 0x44]),
        T::write(A, vec![0x10, 0x40]),
        T::write(A, vec![0x0B, 0x80]), // pulsed data-ready
        T::write(A, vec![0x0D, 0x01]),
        T::write_read(A, vec![0x20], vec![0x00, 0x02]), // +512 LSB = +2 °C at 256/°C
    ];
    let mut bus = Mock::new(&t);
    let mut acc = Accelerometer::detect(bus.clone()).unwrap();
    assert_eq!(acc.chip(), Chip::Lsm6ds3trc);
    assert_eq!(acc.read_temperature_centi_c().unwrap(), 2700);
    bus.done();
}

#[test]
fn the_second_address_is_tried() {
    let t = vec![
        nack(0x6A, 0x0F),
        T::write_read(0x6B, vec![0x0F], vec![0x6A]),
        T::write_read(0x6B, vec![0x0F], vec![0x6A]),
        T::write(0x6B, vec![0x12, 0x44]),
        T::write(0x6B, vec![0x10, 0x40]),
        T::write(0x6B, vec![0x0B, 0x80]),
        T::write(0x6B, vec![0x0D, 0x01]),
    ];
    let mut bus = Mock::new(&t);
    let acc = Accelerometer::detect(bus.clone()).unwrap();
    assert_eq!(acc.address(), 0x6B);
    bus.done();
}

#[test]
fn absent_and_unknown_chips_are_reported_with_the_bus() {
    let mut bus = Mock::new(&[nack(0x6A, 0x0F), nack(0x6B, 0x0F)]);
    let (_, e) = Accelerometer::detect(bus.clone()).unwrap_err();
    assert_eq!(e, Error::Absent);
    bus.done();

    let t = vec![
        T::write_read(A, vec![0x0F], vec![0x33]),
        T::write_read(A, vec![0x0F], vec![0x33]),
        nack(0x6B, 0x0F),
    ];
    let mut bus = Mock::new(&t);
    let (_, e) = Accelerometer::detect(bus.clone()).unwrap_err();
    assert_eq!(e, Error::UnknownChip(0x33));
    bus.done();
}

#[test]
fn a_bus_fault_while_reading_is_an_error_not_a_panic() {
    let mut t = lsm6ds33_setup();
    t.push(T::write_read(A, vec![0x28], vec![0; 6]).with_error(MockError::Io(ErrorKind::Other)));
    let mut bus = Mock::new(&t);
    let mut acc = Accelerometer::detect(bus.clone()).unwrap();
    assert!(matches!(acc.read_counts(), Err(Error::Bus(_))));
    bus.done();
}
