//! The MTData2 fields the daemon uses, gathered into one fixed, copyable struct.

use crate::mtdata2::{items, DataItem, Mtdata2Error, UtcTime, Values};

/// One MTData2 message; fields the message did not carry are `None`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Measurement {
    pub packet_counter: Option<u16>,
    pub sample_time_fine: Option<u32>,
    pub status_word: Option<u32>,
    pub acceleration: Option<Values<3>>,
    pub rate_of_turn: Option<Values<3>>,
    pub delta_v: Option<Values<3>>,
    pub delta_q: Option<Values<4>>,
    pub quaternion: Option<Values<4>>,
    pub euler_angles: Option<Values<3>>,
    pub free_acceleration: Option<Values<3>>,
    pub magnetic_field: Option<Values<3>>,
    pub temperature: Option<f64>,
    pub utc_time: Option<UtcTime>,
}

impl Measurement {
    /// Decodes a whole MTData2 payload; other items are skipped.
    pub fn from_payload(payload: &[u8]) -> Result<Self, Mtdata2Error> {
        let mut m = Self::default();
        for item in items(payload) {
            m.absorb(item?);
        }
        Ok(m)
    }

    fn absorb(&mut self, item: DataItem<'_>) {
        match item {
            DataItem::PacketCounter(v) => self.packet_counter = Some(v),
            DataItem::SampleTimeFine(v) => self.sample_time_fine = Some(v),
            DataItem::StatusWord(v) => self.status_word = Some(v),
            DataItem::Acceleration(v) => self.acceleration = Some(v),
            DataItem::RateOfTurn(v) => self.rate_of_turn = Some(v),
            DataItem::DeltaV(v) => self.delta_v = Some(v),
            DataItem::DeltaQ(v) => self.delta_q = Some(v),
            DataItem::Quaternion(v) => self.quaternion = Some(v),
            DataItem::EulerAngles(v) => self.euler_angles = Some(v),
            DataItem::FreeAcceleration(v) => self.free_acceleration = Some(v),
            DataItem::MagneticField(v) => self.magnetic_field = Some(v),
            DataItem::Temperature(v) => self.temperature = Some(v.values[0]),
            DataItem::UtcTime(v) => self.utc_time = Some(v),
            _ => {}
        }
    }
}
