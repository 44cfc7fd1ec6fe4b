// battery_screen: the robot's battery on its screen, once a second. A complete icefloe service
// in C++ with zenoh-cpp 1.x: the same service as examples/c and examples/curl_service.sh.
//
//   subscribes  icefloe/<robot>/hw/battery   BatteryReading, MessagePack (battery.cpp)
//   publishes   icefloe/<robot>/oled/text    OledText, JSON
//   holds       icefloe/<robot>/alive/<service>, so `icefloe status` lists it
//
// Under `icefloe up` ([programs.battery_screen] in the robot config) it is told the robot, its
// router and its credentials file in ICEFLOE_ROBOT, ICEFLOE_CONNECT and ICEFLOE_CREDENTIALS
// (docs/own-services.md). Ctrl-C (SIGINT) or SIGTERM ends it cleanly.
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <mutex>
#include <optional>
#include <regex>
#include <string>
#include <thread>

#include "battery.hpp"
#include "zenoh.hxx"

namespace {

std::atomic<bool> running{true};

std::string env_or(const char* name, const std::string& fallback) {
    const char* value = std::getenv(name);
    return value && *value ? value : fallback;
}

// `key = "value"` from the robot's credentials file (a TOML file made by `icefloe credentials`).
std::optional<std::string> credential(const std::string& path, const std::string& key) {
    std::ifstream file(path);
    std::regex line_re("^" + key + " *= *\"([^\"]*)\"$");
    std::smatch match;
    for (std::string line; std::getline(file, line);) {
        if (std::regex_match(line, match, line_re)) return match[1];
    }
    return std::nullopt;
}

}  // namespace

int main() {
    const auto robot = env_or("ICEFLOE_ROBOT", "sim");
    const auto service = env_or("ICEFLOE_SERVICE", "battery_screen");
    const auto connect = env_or("ICEFLOE_CONNECT", "tcp/127.0.0.1:7447");
    const auto prefix = "icefloe/" + robot + "/";

    // A client of the robot's router, no multicast scouting: this robot, not any.
    auto config = zenoh::Config::create_default();
    config.insert_json5("mode", "\"client\"");
    config.insert_json5("scouting/multicast/enabled", "false");
    config.insert_json5("connect/endpoints", "[\"" + connect + "\"]");
    if (const char* path = std::getenv("ICEFLOE_CREDENTIALS")) {  // access control: log in as the owner
        auto user = credential(path, "user"), password = credential(path, "password");
        if (!user || !password) {
            std::cerr << "battery_screen: " << path << ": no user or password in it\n";
            return 2;
        }
        config.insert_json5("transport/auth/usrpwd/user", "\"" + *user + "\"");
        config.insert_json5("transport/auth/usrpwd/password", "\"" + *password + "\"");
    }
    zenoh::ZResult err;
    auto session = zenoh::Session::open(std::move(config), zenoh::Session::SessionOptions::create_default(), &err);
    if (err != Z_OK) {
        std::cerr << "battery_screen: cannot reach the robot's router at " << connect << "\n";
        return 1;
    }

    std::mutex lock;  // the newest reading: written on a Zenoh thread, read below
    std::optional<Battery> latest;
    int bad = 0;
    auto subscriber = session.declare_subscriber(
        zenoh::KeyExpr(prefix + "hw/battery"),
        [&](const zenoh::Sample& sample) {
            auto bytes = sample.get_payload().as_vector();
            auto reading = decode_battery(bytes.data(), bytes.size());
            std::lock_guard guard(lock);  // short: never block in a Zenoh callback
            if (reading) latest = reading; else ++bad;
        },
        zenoh::closures::none);
    auto token = session.liveliness_declare_token(zenoh::KeyExpr(prefix + "alive/" + service));  // "I am running"
    auto publisher = session.declare_publisher(zenoh::KeyExpr(prefix + "oled/text"));

    std::signal(SIGINT, [](int) { running = false; });
    std::signal(SIGTERM, [](int) { running = false; });
    std::cout << "battery_screen: showing " << prefix << "hw/battery on the screen of " << robot << std::endl;
    int reported_bad = 0;
    while (running) {
        std::optional<Battery> reading;
        int bad_now;
        {
            std::lock_guard guard(lock);
            reading = latest;
            bad_now = bad;
        }
        if (bad_now != reported_bad) {  // one line per second at most, naming the key
            std::cerr << "battery_screen: " << prefix << "hw/battery: " << bad_now
                      << " samples that are not a BatteryReading\n";
            reported_bad = bad_now;
        }
        if (reading) {
            auto json = battery_text_json(*reading);
            zenoh::Publisher::PutOptions options;
            options.encoding = zenoh::Encoding("application/json");
            publisher.put(zenoh::Bytes(json), std::move(options));
            std::cout << json << std::endl;
        }
        std::this_thread::sleep_for(std::chrono::seconds(1));
    }
    std::cout << "battery_screen: stopped" << std::endl;  // token, subscriber, session: closed as they go
}
