#include "battery.hpp"

#include <cstdio>
#include <map>
#include <msgpack.hpp>

std::optional<Battery> decode_battery(const std::uint8_t* data, std::size_t size) {
    try {
        auto handle = msgpack::unpack(reinterpret_cast<const char*>(data), size);
        // A map by field name: fields in any order, unknown ones ignored (the robot may add some).
        auto fields = handle.get().as<std::map<std::string, msgpack::object>>();
        return Battery{fields.at("stamp").as<std::int64_t>(), fields.at("voltage").as<double>(),
                       fields.at("current").as<double>()};
    } catch (const std::exception&) {  // not MessagePack, not a map, a field missing or mistyped
        return std::nullopt;
    }
}

std::string battery_text_json(const Battery& reading) {
    char json[64];
    std::snprintf(json, sizeof json, "{\"text\": \"battery %.2f V\"}", reading.voltage);
    return json;
}
