//! The messages this service reads and writes, without Zenoh: `hw/battery` (MessagePack, as the
//! robot publishes it) and `oled/text` (JSON, as the robot accepts it). `cargo test` checks them.

use serde::{Deserialize, Serialize};

/// `hw/battery`, schemas/json/BatteryReading.json.
#[derive(Debug, Clone, Deserialize)]
pub struct BatteryReading {
    /// ns since the Unix epoch: more than an f64 holds exactly.
    pub stamp: i64,
    /// V.
    pub voltage: f64,
    /// A.
    pub current: f64,
}

/// `oled/text`, schemas/json/OledText.json.
#[derive(Debug, Serialize)]
pub struct OledText {
    pub text: String,
}

/// A BatteryReading from a MessagePack map keyed by field name (serde matches fields by name,
/// in any order; fields the robot may add later are ignored).
pub fn decode(bytes: &[u8]) -> Result<BatteryReading, rmp_serde::decode::Error> {
    rmp_serde::from_slice(bytes)
}

/// The OledText message showing it, as JSON: `{"text":"battery 7.40 V"}`.
pub fn text_json(reading: &BatteryReading) -> String {
    serde_json::to_string(&OledText { text: format!("battery {:.2} V", reading.voltage) }).unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_map_by_field_name_and_writes_json() {
        // What icefloe publishes: a map {"stamp", "voltage", "current"} (rmp_serde's to_vec_named
        // writes the same; its to_vec writes an array, which the robot refuses).
        #[derive(Serialize)]
        struct Sent { current: f64, stamp: i64, voltage: f64 }
        let bytes = rmp_serde::to_vec_named(&Sent { current: 0.3, stamp: 1_800_000_000_000_000_001, voltage: 7.4 }).unwrap();
        let reading = decode(&bytes).unwrap();
        assert_eq!(reading.stamp, 1_800_000_000_000_000_001);
        assert_eq!(text_json(&reading), r#"{"text":"battery 7.40 V"}"#);
        assert!(decode(b"xx").is_err()); // not MessagePack
    }
}
