//! Freeing an I²C bus that the sensor holds. A slave that was sending when its master
//! stopped clocking (the board reset mid-transfer, a brown-out, a noise spike on SCL) keeps
//! SDA low for as long as its current bit is a 0, and waits for clocks that never come:
//! every later transfer then times out. The I²C specification's remedy (NXP UM10204 rev. 7,
//! §3.1.16 "Bus clear"): clock SCL, up to nine times, until the slave lets SDA go (it has
//! shifted out its byte and sees the master's NACK), then send a STOP so that every device
//! is idle.
//!
//! The firmware drives the two lines as open-drain GPIOs through [`Lines`] while its TWIM is
//! released; this module decides what to do with them, and the host tests it against a
//! model of a slave stuck in each bit of each byte.

/// The two lines, open-drain: "high" releases a line to its pull-up.
pub trait Lines {
    /// Release SCL (`true`) or pull it low.
    fn set_scl(&mut self, high: bool);
    /// Release SDA (`true`) or pull it low.
    fn set_sda(&mut self, high: bool);
    /// Whether SDA reads high (nothing pulls it low).
    fn sda_is_high(&mut self) -> bool;
    /// Whether SCL reads high (a slave may stretch it).
    fn scl_is_high(&mut self) -> bool;
    /// Wait half a clock period (5 µs: 100 kHz, the slowest speed every slave takes).
    fn half_period(&mut self);
}

/// Clocks a bus clear gives at most: a byte's 8 bits and the ninth, the acknowledge.
pub const MAX_CLOCKS: u8 = 9;

/// Half periods to wait for a slave that stretches SCL before giving up on it (1 ms).
const STRETCH_LIMIT: u16 = 200;

/// How a bus clear ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Recovery {
    /// SDA was already high: only the STOP was sent.
    WasFree,
    /// SDA went high after this many clocks, and the STOP was sent.
    Freed {
        /// Clocks given, a STOP tried on a slave that took SDA again counted as one (1 to
        /// [`MAX_CLOCKS`] + 1).
        clocks: u8,
    },
    /// SDA still low after [`MAX_CLOCKS`] clocks: something other than a waiting slave holds
    /// it (a short, a dead sensor).
    SdaStuck,
    /// SCL stays low: a slave stretches it for ever, or the line is shorted.
    SclStuck,
}

/// Clear the bus: see the module documentation. Leaves both lines released.
///
/// Whenever SDA reads high a STOP is tried (SCL low, SDA low, SCL high, SDA released): its
/// SCL low is a clock too, on which a slave in the middle of a byte may take SDA for its
/// next bit, so the STOP is on the wire only if SDA reads high after it; otherwise the
/// clocking goes on.
pub fn recover<L: Lines>(l: &mut L) -> Recovery {
    l.set_sda(true);
    l.set_scl(true);
    if !wait_scl(l) {
        return Recovery::SclStuck;
    }
    let mut clocks: u8 = 0;
    loop {
        if l.sda_is_high() {
            l.set_scl(false);
            l.half_period();
            l.set_sda(false);
            l.half_period();
            l.set_scl(true);
            if !wait_scl(l) {
                return Recovery::SclStuck;
            }
            l.set_sda(true);
            l.half_period();
            if l.sda_is_high() {
                return match clocks {
                    0 => Recovery::WasFree,
                    clocks => Recovery::Freed { clocks },
                };
            }
        } else {
            if clocks >= MAX_CLOCKS {
                return Recovery::SdaStuck;
            }
            l.set_scl(false);
            l.half_period();
            l.set_scl(true);
            if !wait_scl(l) {
                return Recovery::SclStuck;
            }
        }
        // A slave finishes its byte in nine clocks: the STOP tries can add one.
        clocks += 1;
        if clocks > MAX_CLOCKS + 1 {
            return Recovery::SdaStuck;
        }
    }
}

/// Wait for SCL to read high after its release (clock stretching), a half period at least.
fn wait_scl<L: Lines>(l: &mut L) -> bool {
    l.half_period();
    for _ in 0..STRETCH_LIMIT {
        if l.scl_is_high() {
            return true;
        }
        l.half_period();
    }
    false
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    extern crate std;
    use proptest::prelude::*;
    use std::vec::Vec;

    /// A slave interrupted while sending `byte`, at bit `next` (0 = the MSB; 8 = the
    /// acknowledge bit, which the master gives and the slave does not drive): it drives SDA
    /// with its current bit, shifts at each falling SCL edge, and after its eighth bit
    /// reads the master's acknowledge on the ninth clock; a NACK (SDA high) ends its
    /// transfer. A STOP (SDA rising while SCL is high) makes every device idle.
    struct Bus {
        byte: u8,
        next: u8,
        done: bool,
        stuck_sda: bool,
        stuck_scl: bool,
        master_scl: bool,
        master_sda: bool,
        /// (SCL, SDA) on the wire after every change, for the checks.
        trace: Vec<(bool, bool)>,
        stops: u32,
    }

    impl Bus {
        fn new(byte: u8, next: u8) -> Self {
            Bus {
                byte,
                next,
                done: false,
                stuck_sda: false,
                stuck_scl: false,
                master_scl: true,
                master_sda: true,
                trace: Vec::new(),
                stops: 0,
            }
        }

        fn slave_sda(&self) -> bool {
            if self.stuck_sda {
                return false;
            }
            if self.done || self.next >= 8 {
                return true;
            }
            self.byte & (0x80 >> self.next) != 0
        }

        fn scl(&self) -> bool {
            self.master_scl && !self.stuck_scl
        }

        fn sda(&self) -> bool {
            self.master_sda && self.slave_sda()
        }

        fn record(&mut self) {
            self.trace.push((self.scl(), self.sda()));
        }
    }

    impl Lines for Bus {
        fn set_scl(&mut self, high: bool) {
            let (was, sda) = (self.scl(), self.sda());
            self.master_scl = high;
            if was && !self.scl() && !self.done {
                // Falling edge: the slave moves to its next bit; after the ninth (the
                // acknowledge) a NACK ends the transfer.
                if self.next == 8 {
                    self.done = sda;
                    self.next = 0;
                } else {
                    self.next += 1;
                }
            }
            self.record();
        }

        fn set_sda(&mut self, high: bool) {
            let was = self.sda();
            self.master_sda = high;
            if self.scl() && !was && self.sda() {
                self.stops += 1;
                self.done = true;
            }
            self.record();
        }

        fn sda_is_high(&mut self) -> bool {
            self.sda()
        }

        fn scl_is_high(&mut self) -> bool {
            self.scl()
        }

        fn half_period(&mut self) {}
    }

    proptest! {
        #[test]
        fn a_slave_stuck_anywhere_in_a_byte_is_freed_and_the_bus_stopped(
            byte in any::<u8>(),
            next in 0u8..=8,
        ) {
            let mut bus = Bus::new(byte, next);
            let r = recover(&mut bus);
            match r {
                // At once only where SDA was high (a 1 bit, or the acknowledge's).
                Recovery::WasFree => prop_assert!(Bus::new(byte, next).slave_sda()),
                Recovery::Freed { clocks } => prop_assert!((1..=MAX_CLOCKS + 1).contains(&clocks)),
                other => prop_assert!(false, "{other:?}"),
            }
            // Ends with one STOP, both lines released, the slave idle.
            prop_assert_eq!(bus.stops, 1);
            prop_assert!(bus.scl() && bus.sda() && bus.done);
            // And no START: SDA never falls while SCL is high.
            let starts = bus
                .trace
                .windows(2)
                .filter(|w| w[0].0 && w[1].0 && w[0].1 && !w[1].1)
                .count();
            prop_assert_eq!(starts, 0);
        }
    }

    #[test]
    fn the_worst_case_takes_all_nine_clocks() {
        // The slave has just driven the MSB of 0x00: seven more zeros to shift out, then it
        // lets SDA go for the acknowledge; the STOP's own clock is the ninth, on which it
        // reads the NACK.
        let mut bus = Bus::new(0x00, 0);
        assert_eq!(recover(&mut bus), Recovery::Freed { clocks: 8 });
        let falls = bus.trace.windows(2).filter(|w| w[0].0 && !w[1].0).count();
        assert_eq!(falls, 9);
    }

    #[test]
    fn a_line_held_for_ever_is_named() {
        let mut bus = Bus::new(0x00, 0);
        bus.stuck_sda = true;
        assert_eq!(recover(&mut bus), Recovery::SdaStuck);
        // Exactly nine clocks were given: nine falling SCL edges.
        let falls = bus.trace.windows(2).filter(|w| w[0].0 && !w[1].0).count();
        assert_eq!(falls, 9);
        let mut bus = Bus::new(0x00, 0);
        bus.stuck_scl = true;
        assert_eq!(recover(&mut bus), Recovery::SclStuck);
    }
}
