// The messages this service reads and writes, without Zenoh: hw/battery (MessagePack, as the
// robot publishes it) and oled/text (JSON, as the robot accepts it). Kept apart from main so it
// can be tested on a machine without zenoh-cpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

// hw/battery, schemas/json/BatteryReading.json
struct Battery {
    std::int64_t stamp;  // ns since the Unix epoch: more than a double holds exactly
    double voltage;      // V
    double current;      // A
};

// A BatteryReading from a MessagePack map keyed by field name; nothing if it is not one.
std::optional<Battery> decode_battery(const std::uint8_t* data, std::size_t size);

// The OledText message showing it, as JSON: {"text": "battery 7.40 V"}.
std::string battery_text_json(const Battery& reading);
