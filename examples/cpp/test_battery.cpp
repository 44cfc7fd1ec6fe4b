// battery.cpp on its own: MessagePack on stdin, the JSON to send on stdout (exit 1 if it does
// not decode). tests/test_other_languages.py feeds it what icefloe publishes.
#include <iostream>
#include <iterator>
#include <vector>

#include "battery.hpp"

int main() {
    std::vector<std::uint8_t> data(std::istreambuf_iterator<char>(std::cin), {});
    auto reading = decode_battery(data.data(), data.size());
    if (!reading) {
        std::cerr << "not a BatteryReading\n";
        return 1;
    }
    std::cout << reading->stamp << ' ' << battery_text_json(*reading) << '\n';
}
