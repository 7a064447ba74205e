//! ROS 2 messages as serde structs in their IDL field order, encoded with CDR (little
//! endian, XCDR1) exactly as a ROS 2 DDS peer puts them on the wire and rosbag2 stores them.
//! Each type carries its ROS name, its DDS type name and its full `ros2msg` definition
//! (the message, then every dependency after a line of 80 `=`), as MCAP schemas need.

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::core::{ImuSample, PoseSample, TemperatureSample};

/// CDR little-endian encapsulation header (representation id 0x0001, options 0).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
const CDR_BE_HEADER: [u8; 4] = [0x00, 0x00, 0x00, 0x00];

#[derive(Debug, thiserror::Error)]
pub enum MsgError {
    #[error("{type_name}: payload of {len} bytes is too short for a CDR encapsulation header")]
    Short { type_name: &'static str, len: usize },
    #[error(
        "{type_name}: unsupported CDR encapsulation {header:02x?} (expected plain CDR, XCDR1){}",
        if *header == [0x28, 0xb5, 0x2f, 0xfd] { ": the message is zstd-compressed (rosbag2 --compression-mode message); decompress the bag first (`ros2 bag convert` without compression)" } else { "" }
    )]
    Encapsulation { type_name: &'static str, header: [u8; 4] },
    #[error("{type_name}: CDR decode failed: {source}")]
    Decode {
        type_name: &'static str,
        #[source]
        source: cdr_encoding::Error,
    },
    #[error("{type_name}: CDR encode failed: {source}")]
    Encode {
        type_name: &'static str,
        #[source]
        source: cdr_encoding::Error,
    },
}

/// A ROS 2 message type.
pub trait RosMessage: Serialize + DeserializeOwned {
    /// ROS name, e.g. `sensor_msgs/msg/Imu`.
    const TYPE_NAME: &'static str;
    /// Full `ros2msg` definition with dependencies, as rosbag2 writes it.
    const DEFINITION: &'static str;

    /// DDS type name, e.g. `sensor_msgs::msg::dds_::Imu_`.
    fn dds_type_name() -> String {
        let mut parts = Self::TYPE_NAME.split('/');
        let (pkg, sub, name) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""), parts.next().unwrap_or(""));
        format!("{pkg}::{sub}::dds_::{name}_")
    }

    /// Encode with the CDR encapsulation header into `out` (cleared first; reused buffers
    /// keep the per-sample path allocation-free).
    fn encode_into(&self, out: &mut Vec<u8>) -> Result<(), MsgError> {
        out.clear();
        out.extend_from_slice(&CDR_LE_HEADER);
        cdr_encoding::to_writer::<_, byteorder::LittleEndian, _>(&mut *out, self)
            .map_err(|source| MsgError::Encode { type_name: Self::TYPE_NAME, source })
    }

    /// Encode with the CDR encapsulation header.
    fn encode(&self) -> Result<Vec<u8>, MsgError> {
        let mut out = Vec::with_capacity(128);
        self.encode_into(&mut out)?;
        Ok(out)
    }

    /// Decode a payload that starts with a CDR encapsulation header (either endianness).
    fn decode(bytes: &[u8]) -> Result<Self, MsgError> {
        if bytes.len() < 4 {
            return Err(MsgError::Short { type_name: Self::TYPE_NAME, len: bytes.len() });
        }
        let header = [bytes[0], bytes[1], bytes[2], bytes[3]];
        let body = &bytes[4..];
        let res = if header[..2] == CDR_LE_HEADER[..2] {
            cdr_encoding::from_bytes::<Self, byteorder::LittleEndian>(body)
        } else if header[..2] == CDR_BE_HEADER[..2] {
            cdr_encoding::from_bytes::<Self, byteorder::BigEndian>(body)
        } else {
            return Err(MsgError::Encapsulation { type_name: Self::TYPE_NAME, header });
        };
        res.map(|(m, _)| m).map_err(|source| MsgError::Decode { type_name: Self::TYPE_NAME, source })
    }
}

/// Separator between a definition and each dependency in a `ros2msg` schema.
macro_rules! sep {
    () => {
        "================================================================================\n"
    };
}

/// The dependencies' sections of a `ros2msg` schema, in the order given: for each, the
/// separator, `MSG: <type>` and its fields, each type's text written once here.
macro_rules! deps {
    ($($dep:ident),+) => { concat!($(sep!(), deps!(@ $dep)),+) };
    (@ Header) => { "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n" };
    (@ Time) => { "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n" };
    (@ Quaternion) => { "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n" };
    (@ Vector3) => { "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n" };
    (@ Point) => { "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n" };
    (@ Pose) => { "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n" };
    (@ PoseWithCovariance) => { "MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n" };
    (@ TwistWithCovariance) => { "MSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist twist\nfloat64[36] covariance\n" };
    (@ Twist) => { "MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n" };
    (@ DiagnosticStatus) => {
        concat!(
            "MSG: diagnostic_msgs/DiagnosticStatus\n",
            "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\n",
            "byte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values\n"
        )
    };
    (@ KeyValue) => { "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value\n" };
}

/// builtin_interfaces/msg/Time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From ROS time in ns (negative stamps are clamped to 0, which ROS cannot express).
    /// Clamped to what the message holds (`sec` is an int32: 1970 to 2038), not wrapped.
    pub fn from_ns(ns: i64) -> Self {
        const MAX_NS: i64 = i32::MAX as i64 * 1_000_000_000 + 999_999_999;
        let ns = ns.clamp(0, MAX_NS);
        Time { sec: (ns / 1_000_000_000) as i32, nanosec: (ns % 1_000_000_000) as u32 }
    }
    pub fn to_ns(self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
}

/// std_msgs/msg/Header.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// geometry_msgs/msg/Vector3 (and Point, which has the same layout).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl From<nalgebra::Vector3<f64>> for Vector3 {
    fn from(v: nalgebra::Vector3<f64>) -> Self {
        Vector3 { x: v.x, y: v.y, z: v.z }
    }
}
impl From<Vector3> for nalgebra::Vector3<f64> {
    fn from(v: Vector3) -> Self {
        nalgebra::Vector3::new(v.x, v.y, v.z)
    }
}

/// geometry_msgs/msg/Quaternion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}
impl From<nalgebra::UnitQuaternion<f64>> for Quaternion {
    fn from(q: nalgebra::UnitQuaternion<f64>) -> Self {
        Quaternion { x: q.i, y: q.j, z: q.k, w: q.w }
    }
}
impl Quaternion {
    /// As a unit quaternion, normalised; `None` if not finite or of zero norm.
    pub fn to_unit(&self) -> Option<nalgebra::UnitQuaternion<f64>> {
        let q = nalgebra::Quaternion::new(self.w, self.x, self.y, self.z);
        let n = q.norm();
        (n.is_finite() && n > 1e-9).then(|| nalgebra::UnitQuaternion::new_normalize(q))
    }
}

/// A fixed-size float64 array of ROS (`float64[N]`): CDR writes it without a length.
/// serde implements arrays only up to 32, so 36-element covariances need this.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixedF64<const N: usize>(pub [f64; N]);

impl<const N: usize> Default for FixedF64<N> {
    fn default() -> Self {
        FixedF64([0.0; N])
    }
}

impl<const N: usize> Serialize for FixedF64<N> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(N)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de, const N: usize> Deserialize<'de> for FixedF64<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<const N: usize>;
        impl<'de, const N: usize> serde::de::Visitor<'de> for V<N> {
            type Value = FixedF64<N>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "{N} float64 values")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut out = [0.0; N];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq.next_element()?.ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                }
                Ok(FixedF64(out))
            }
        }
        d.deserialize_tuple(N, V::<N>)
    }
}

/// sensor_msgs/msg/Imu.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Imu {
    pub header: Header,
    pub orientation: Quaternion,
    pub orientation_covariance: FixedF64<9>,
    pub angular_velocity: Vector3,
    pub angular_velocity_covariance: FixedF64<9>,
    pub linear_acceleration: Vector3,
    pub linear_acceleration_covariance: FixedF64<9>,
}

impl RosMessage for Imu {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/Imu";
    const DEFINITION: &'static str = concat!(
        "std_msgs/Header header\n",
        "geometry_msgs/Quaternion orientation\n",
        "float64[9] orientation_covariance\n",
        "geometry_msgs/Vector3 angular_velocity\n",
        "float64[9] angular_velocity_covariance\n",
        "geometry_msgs/Vector3 linear_acceleration\n",
        "float64[9] linear_acceleration_covariance\n",
        deps!(Header, Time, Quaternion, Vector3),
    );
}

impl Imu {
    /// A raw IMU message (no orientation: orientation_covariance[0] = −1, as REP 145 says).
    pub fn from_sample(s: &ImuSample, frame_id: &str) -> Self {
        let mut orientation_covariance = FixedF64::default();
        orientation_covariance.0[0] = -1.0;
        Imu {
            header: Header { stamp: Time::from_ns(s.stamp_ns), frame_id: frame_id.to_string() },
            orientation: Quaternion::default(),
            orientation_covariance,
            angular_velocity: s.gyro.into(),
            angular_velocity_covariance: FixedF64::default(),
            linear_acceleration: s.accel.into(),
            linear_acceleration_covariance: FixedF64::default(),
        }
    }

    pub fn sample(&self) -> ImuSample {
        ImuSample { stamp_ns: self.header.stamp.to_ns(), gyro: self.angular_velocity.into(), accel: self.linear_acceleration.into() }
    }

    /// True when the message carries an orientation (REP 145: covariance[0] ≠ −1).
    pub fn has_orientation(&self) -> bool {
        self.orientation_covariance.0[0] != -1.0
    }
}

/// geometry_msgs/msg/Pose.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// geometry_msgs/msg/PoseStamped.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

impl RosMessage for PoseStamped {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/PoseStamped";
    const DEFINITION: &'static str =
        concat!("std_msgs/Header header\n", "geometry_msgs/Pose pose\n", deps!(Header, Time, Pose, Point, Quaternion));
}

impl PoseStamped {
    pub fn from_sample(p: &PoseSample, frame_id: &str) -> Self {
        PoseStamped {
            header: Header { stamp: Time::from_ns(p.stamp_ns), frame_id: frame_id.to_string() },
            pose: Pose { position: p.position_in_world.into(), orientation: p.world_from_body.into() },
        }
    }

    /// As a pose sample; `None` when the quaternion is not a rotation.
    pub fn sample(&self) -> Option<PoseSample> {
        pose_sample(self.header.stamp.to_ns(), &self.pose)
    }
}

fn pose_sample(stamp_ns: i64, pose: &Pose) -> Option<PoseSample> {
    let position_in_world: nalgebra::Vector3<f64> = pose.position.into();
    if !position_in_world.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(PoseSample { stamp_ns, position_in_world, world_from_body: pose.orientation.to_unit()? })
}

/// geometry_msgs/msg/Vector3Stamped.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3Stamped {
    pub header: Header,
    pub vector: Vector3,
}

impl RosMessage for Vector3Stamped {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Vector3Stamped";
    const DEFINITION: &'static str = concat!("std_msgs/Header header\n", "geometry_msgs/Vector3 vector\n", deps!(Header, Time, Vector3));
}

/// geometry_msgs/msg/PoseWithCovariance.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: FixedF64<36>,
}

/// geometry_msgs/msg/Twist.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// geometry_msgs/msg/TwistWithCovariance.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: FixedF64<36>,
}

/// nav_msgs/msg/Odometry.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

impl RosMessage for Odometry {
    const TYPE_NAME: &'static str = "nav_msgs/msg/Odometry";
    const DEFINITION: &'static str = concat!(
        "std_msgs/Header header\n",
        "string child_frame_id\n",
        "geometry_msgs/PoseWithCovariance pose\n",
        "geometry_msgs/TwistWithCovariance twist\n",
        deps!(Header, Time, PoseWithCovariance, Pose, Point, Quaternion, TwistWithCovariance, Twist, Vector3),
    );
}

impl Odometry {
    /// The pose part as a pose sample (child frame in the header frame).
    pub fn sample(&self) -> Option<PoseSample> {
        pose_sample(self.header.stamp.to_ns(), &self.pose.pose)
    }
}

/// sensor_msgs/msg/Temperature.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Temperature {
    pub header: Header,
    pub temperature: f64,
    pub variance: f64,
}

impl RosMessage for Temperature {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/Temperature";
    const DEFINITION: &'static str =
        concat!("std_msgs/Header header\n", "float64 temperature\n", "float64 variance\n", deps!(Header, Time));
}

impl Temperature {
    pub fn sample(&self) -> TemperatureSample {
        TemperatureSample { stamp_ns: self.header.stamp.to_ns(), celsius: self.temperature }
    }
}

/// diagnostic_msgs/msg/KeyValue.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// diagnostic_msgs/msg/DiagnosticStatus.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// One of [`DiagnosticStatus::OK`], `WARN`, `ERROR`, `STALE`.
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// diagnostic_msgs/msg/DiagnosticArray.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

impl RosMessage for DiagnosticArray {
    const TYPE_NAME: &'static str = "diagnostic_msgs/msg/DiagnosticArray";
    const DEFINITION: &'static str =
        concat!("std_msgs/Header header\n", "DiagnosticStatus[] status\n", deps!(Header, Time, DiagnosticStatus, KeyValue));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> Header {
        Header { stamp: Time { sec: 1403636579, nanosec: 758555648 }, frame_id: "imu_link".into() }
    }

    /// Beyond what an int32 second holds, a stamp is clamped, never wrapped to 1901.
    #[test]
    fn time_from_ns_clamps() {
        assert_eq!(Time::from_ns(1_403_636_579_758_555_648).to_ns(), 1_403_636_579_758_555_648);
        assert_eq!(Time::from_ns(-5), Time { sec: 0, nanosec: 0 });
        assert_eq!(Time::from_ns(i64::MAX), Time { sec: i32::MAX, nanosec: 999_999_999 });
    }

    #[test]
    fn imu_round_trip_and_layout() {
        let mut m = Imu::from_sample(
            &ImuSample {
                stamp_ns: 1_403_636_579_758_555_648,
                gyro: nalgebra::Vector3::new(0.1, -0.2, 0.3),
                accel: nalgebra::Vector3::new(9.0, 0.5, -1.0),
            },
            "imu_link",
        );
        m.angular_velocity_covariance.0[4] = 1e-6;
        let bytes = m.encode().unwrap();
        assert_eq!(&bytes[..4], &CDR_LE_HEADER);
        // header: 4+4 stamp, 4 len + "imu_link\0" (9) → 21, pad to 24; then 4+9+3+9+3+9 doubles.
        assert_eq!(bytes.len(), 4 + 24 + 8 * (4 + 9 + 3 + 9 + 3 + 9));
        assert_eq!(Imu::decode(&bytes).unwrap(), m);
        assert_eq!(m.sample().stamp_ns, 1_403_636_579_758_555_648);
        assert!(!m.has_orientation());
    }

    #[test]
    fn every_type_round_trips() {
        let pose = PoseStamped {
            header: header(),
            pose: Pose { position: Vector3 { x: 1.0, y: 2.0, z: 3.0 }, orientation: Quaternion { x: 0.0, y: 0.0, z: 0.6, w: 0.8 } },
        };
        assert_eq!(PoseStamped::decode(&pose.encode().unwrap()).unwrap(), pose);
        let v = Vector3Stamped { header: header(), vector: Vector3 { x: 1e-3, y: -2.0, z: 5.0 } };
        assert_eq!(Vector3Stamped::decode(&v.encode().unwrap()).unwrap(), v);
        let mut odom = Odometry { header: header(), child_frame_id: "base_link".into(), ..Default::default() };
        odom.pose.covariance.0[35] = 0.5;
        odom.twist.twist.angular.z = 0.25;
        assert_eq!(Odometry::decode(&odom.encode().unwrap()).unwrap(), odom);
        let t = Temperature { header: header(), temperature: 31.5, variance: 0.01 };
        assert_eq!(Temperature::decode(&t.encode().unwrap()).unwrap(), t);
        let d = DiagnosticArray {
            header: header(),
            status: vec![DiagnosticStatus {
                level: DiagnosticStatus::WARN,
                name: "imu_fsda: node".into(),
                message: "warm-up".into(),
                hardware_id: "imu".into(),
                values: vec![KeyValue { key: "rate_hz".into(), value: "200".into() }],
            }],
        };
        assert_eq!(DiagnosticArray::decode(&d.encode().unwrap()).unwrap(), d);
    }

    #[test]
    fn big_endian_payloads_decode() {
        let t = Temperature { header: header(), temperature: -3.25, variance: 0.0 };
        let mut be = CDR_BE_HEADER.to_vec();
        be.extend(cdr_encoding::to_vec::<_, byteorder::BigEndian>(&t).unwrap());
        assert_eq!(Temperature::decode(&be).unwrap(), t);
    }

    #[test]
    fn truncated_and_foreign_payloads_are_errors() {
        let bytes = Imu::default().encode().unwrap();
        assert!(matches!(Imu::decode(&bytes[..2]), Err(MsgError::Short { .. })));
        assert!(matches!(Imu::decode(&bytes[..40]), Err(MsgError::Decode { .. })));
        let mut xcdr2 = bytes.clone();
        xcdr2[1] = 0x07;
        assert!(matches!(Imu::decode(&xcdr2), Err(MsgError::Encapsulation { .. })));
    }

    #[test]
    fn dds_type_names() {
        assert_eq!(Imu::dds_type_name(), "sensor_msgs::msg::dds_::Imu_");
        assert_eq!(DiagnosticArray::dds_type_name(), "diagnostic_msgs::msg::dds_::DiagnosticArray_");
    }
}
