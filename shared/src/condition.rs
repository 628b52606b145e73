//! The rotation conditions, which platter axis the device turns about (docs/method.md §1), and
//! the sensor's channels. With the `serde` feature both are written as their letters.

/// A condition, named by the platter axis of rotation. Gravity in the platter frame is
/// ĝ(α) = (0, sin α, cos α) about x, (sin α, 0, cos α) about y, (sin α, cos α, 0) about z.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "lowercase")
)]
pub enum Condition {
    /// Rotation about the platter's x axis.
    #[cfg_attr(feature = "serde", serde(alias = "X"))]
    X,
    /// Rotation about the platter's y axis.
    #[cfg_attr(feature = "serde", serde(alias = "Y"))]
    Y,
    /// Rotation about the platter's z axis.
    #[cfg_attr(feature = "serde", serde(alias = "Z"))]
    Z,
}

impl Condition {
    /// All three, in order.
    pub const ALL: [Condition; 3] = [Condition::X, Condition::Y, Condition::Z];

    /// 0, 1, 2 for x, y, z.
    pub const fn index(self) -> usize {
        match self {
            Condition::X => 0,
            Condition::Y => 1,
            Condition::Z => 2,
        }
    }

    /// The platter axes whose sensitivity components A (with sin α) and B (with cos α)
    /// measure: about x, A ↔ S_jy and B ↔ S_jz; about y, x and z; about z, x and y.
    pub const fn sin_cos_axes(self) -> (usize, usize) {
        match self {
            Condition::X => (1, 2),
            Condition::Y => (0, 2),
            Condition::Z => (0, 1),
        }
    }

    /// This condition's element of a per-condition array (no index to check).
    pub const fn of<T>(self, per_condition: &[T; 3]) -> &T {
        let [x, y, z] = per_condition;
        match self {
            Condition::X => x,
            Condition::Y => y,
            Condition::Z => z,
        }
    }

    /// This condition's element of a per-condition array, to change.
    pub fn of_mut<T>(self, per_condition: &mut [T; 3]) -> &mut T {
        let [x, y, z] = per_condition;
        match self {
            Condition::X => x,
            Condition::Y => y,
            Condition::Z => z,
        }
    }

    /// The letter used in files: `x`, `y` or `z`.
    pub const fn letter(self) -> char {
        match self {
            Condition::X => 'x',
            Condition::Y => 'y',
            Condition::Z => 'z',
        }
    }

    /// ĝ(α), the direction of gravity's reading in the platter frame at table angle
    /// `alpha_rad` (docs/method.md §1): the sign convention of the conditions, in one place.
    pub fn gravity_direction(self, alpha_rad: f64) -> [f64; 3] {
        let (s, c) = (libm::sin(alpha_rad), libm::cos(alpha_rad));
        match self {
            Condition::X => [0.0, s, c],
            Condition::Y => [s, 0.0, c],
            Condition::Z => [s, c, 0.0],
        }
    }

    /// From the letter used in files (lower or upper case).
    pub const fn from_letter(c: char) -> Option<Condition> {
        match c {
            'x' | 'X' => Some(Condition::X),
            'y' | 'Y' => Some(Condition::Y),
            'z' | 'Z' => Some(Condition::Z),
            _ => None,
        }
    }
}

/// A channel of the accelerometer: its sensitive axes u, v and w (the device's x, y and z
/// outputs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "lowercase")
)]
pub enum Channel {
    /// The first output (the device's x).
    U,
    /// The second output (the device's y).
    V,
    /// The third output (the device's z).
    W,
}

impl Channel {
    /// All three, in order.
    pub const ALL: [Channel; 3] = [Channel::U, Channel::V, Channel::W];

    /// 0, 1, 2 for u, v, w: the channel's place in a reading `[u, v, w]`.
    pub const fn index(self) -> usize {
        match self {
            Channel::U => 0,
            Channel::V => 1,
            Channel::W => 2,
        }
    }

    /// The letter used in files: `u`, `v` or `w`.
    pub const fn letter(self) -> char {
        match self {
            Channel::U => 'u',
            Channel::V => 'v',
            Channel::W => 'w',
        }
    }

    /// This channel's element of a per-channel array (no index to check).
    pub const fn of<T>(self, per_channel: &[T; 3]) -> &T {
        match self {
            Channel::U => &per_channel[0],
            Channel::V => &per_channel[1],
            Channel::W => &per_channel[2],
        }
    }

    /// This channel's element of a per-channel array, to change it.
    pub fn of_mut<T>(self, per_channel: &mut [T; 3]) -> &mut T {
        let [u, v, w] = per_channel;
        match self {
            Channel::U => u,
            Channel::V => v,
            Channel::W => w,
        }
    }
}

impl core::fmt::Display for Condition {
    /// The letter used in files.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}", self.letter())
    }
}

impl core::fmt::Display for Channel {
    /// The letter used in files.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}", self.letter())
    }
}
