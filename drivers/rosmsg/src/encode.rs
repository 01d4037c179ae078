//! The same messages written, for tests and benchmarks that make ROS recordings. Written apart
//! from the reader (fields in the order of the `.msg` files, alignment by hand) so that a
//! round trip checks one against the other; the tests also check both against bytes laid out
//! by hand.

use crate::{
    Echoes, Encoding, Header, Imu, LaserScan, Message, MultiEchoLaserScan, Quaternion, ScanInfo,
    TfMessage, Time, Vector3,
};

/// `message` in `encoding`, CDR little-endian (what ROS 2 writes).
pub fn encode(message: &Message, encoding: Encoding) -> Vec<u8> {
    encode_with(message, encoding, false)
}

/// `message` in `encoding`; `big_endian` applies to CDR only.
pub fn encode_with(message: &Message, encoding: Encoding, big_endian: bool) -> Vec<u8> {
    let mut w = Writer {
        cdr: encoding == Encoding::Cdr,
        big_endian: big_endian && encoding == Encoding::Cdr,
        out: Vec::new(),
        origin: 0,
    };
    if w.cdr {
        w.out.extend_from_slice(if w.big_endian {
            &[0, 0, 0, 0]
        } else {
            &[0, 1, 0, 0]
        });
        w.origin = 4;
    }
    match message {
        Message::LaserScan(m) => w.laser_scan(m),
        Message::MultiEchoLaserScan(m) => w.multi_echo(m),
        Message::Imu(m) => w.imu(m),
        Message::Tf(m) => w.tf(m),
    }
    w.out
}

struct Writer {
    cdr: bool,
    big_endian: bool,
    out: Vec<u8>,
    origin: usize,
}

impl Writer {
    fn pad_to(&mut self, size: usize) {
        if self.cdr {
            while !(self.out.len() - self.origin).is_multiple_of(size) {
                self.out.push(0);
            }
        }
    }

    fn u32(&mut self, v: u32) {
        self.pad_to(4);
        let bytes = if self.big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        };
        self.out.extend_from_slice(&bytes);
    }

    fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }

    fn f64(&mut self, v: f64) {
        self.pad_to(8);
        let bits = v.to_bits();
        let bytes = if self.big_endian {
            bits.to_be_bytes()
        } else {
            bits.to_le_bytes()
        };
        self.out.extend_from_slice(&bytes);
    }

    fn string(&mut self, s: &str) {
        let nul = usize::from(self.cdr);
        self.u32((s.len() + nul) as u32);
        self.out.extend_from_slice(s.as_bytes());
        if self.cdr {
            self.out.push(0);
        }
    }

    fn time(&mut self, t: Time) {
        self.u32(t.sec as u32);
        self.u32(t.nanosec);
    }

    fn header(&mut self, h: &Header) {
        if !self.cdr {
            self.u32(h.seq);
        }
        self.time(h.stamp);
        self.string(&h.frame_id);
    }

    fn info(&mut self, i: &ScanInfo) {
        for v in [
            i.angle_min,
            i.angle_max,
            i.angle_increment,
            i.time_increment,
            i.scan_time,
            i.range_min,
            i.range_max,
        ] {
            self.f32(v);
        }
    }

    fn f32s(&mut self, values: &[f32]) {
        self.u32(values.len() as u32);
        for &v in values {
            self.f32(v);
        }
    }

    fn laser_scan(&mut self, m: &LaserScan) {
        self.header(&m.header);
        self.info(&m.info);
        self.f32s(&m.ranges);
        self.f32s(&m.intensities);
    }

    fn echoes(&mut self, e: &Echoes) {
        self.u32(e.beams() as u32);
        for beam in 0..e.beams() {
            self.f32s(e.beam(beam));
        }
    }

    fn multi_echo(&mut self, m: &MultiEchoLaserScan) {
        self.header(&m.header);
        self.info(&m.info);
        self.echoes(&m.ranges);
        self.echoes(&m.intensities);
    }

    fn vector3(&mut self, v: &Vector3) {
        for x in [v.x, v.y, v.z] {
            self.f64(x);
        }
    }

    fn quaternion(&mut self, q: &Quaternion) {
        for x in [q.x, q.y, q.z, q.w] {
            self.f64(x);
        }
    }

    fn covariance(&mut self, c: &[f64; 9]) {
        for &x in c {
            self.f64(x);
        }
    }

    fn imu(&mut self, m: &Imu) {
        self.header(&m.header);
        self.quaternion(&m.orientation);
        self.covariance(&m.orientation_covariance);
        self.vector3(&m.angular_velocity);
        self.covariance(&m.angular_velocity_covariance);
        self.vector3(&m.linear_acceleration);
        self.covariance(&m.linear_acceleration_covariance);
    }

    fn tf(&mut self, m: &TfMessage) {
        self.u32(m.transforms.len() as u32);
        for t in &m.transforms {
            self.header(&t.header);
            self.string(&t.child_frame_id);
            self.vector3(&t.translation);
            self.quaternion(&t.rotation);
        }
    }
}
