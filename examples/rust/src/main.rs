//! battery_screen: the robot's battery on its screen, once a second. A complete icefloe service
//! in Rust with the zenoh crate 1.x: the same service as examples/c, examples/cpp and
//! examples/curl_service.sh.
//!
//!   subscribes  icefloe/<robot>/hw/battery   BatteryReading, MessagePack (battery.rs)
//!   publishes   icefloe/<robot>/oled/text    OledText, JSON
//!   holds       icefloe/<robot>/alive/<service>, so `icefloe status` lists it
//!
//! Under `icefloe up` ([programs.battery_screen] in the robot config) it is told the robot, its
//! router and its credentials file in ICEFLOE_ROBOT, ICEFLOE_CONNECT and ICEFLOE_CREDENTIALS
//! (docs/own-services.md). Ctrl-C (SIGINT) or SIGTERM ends it cleanly.

mod battery;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use std::{env, fs, process};

use zenoh::bytes::Encoding;
use zenoh::Wait;

fn env_or(name: &str, fallback: &str) -> String {
    env::var(name).ok().filter(|v| !v.is_empty()).unwrap_or_else(|| fallback.to_string())
}

/// `key = "value"` from the robot's credentials file (a TOML file made by `icefloe credentials`).
fn credential(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|line| {
        let (name, value) = line.split_once('=')?;
        (name.trim() == key).then(|| value.trim().trim_matches('"').to_string())
    })
}

fn main() {
    let robot = env_or("ICEFLOE_ROBOT", "sim");
    let service = env_or("ICEFLOE_SERVICE", "battery_screen");
    let connect = env_or("ICEFLOE_CONNECT", "tcp/127.0.0.1:7447");
    let prefix = format!("icefloe/{robot}/");

    // A client of the robot's router, no multicast scouting: this robot, not any.
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", r#""client""#).unwrap();
    config.insert_json5("scouting/multicast/enabled", "false").unwrap();
    config.insert_json5("connect/endpoints", &serde_json::json!([connect]).to_string()).unwrap();
    if let Ok(path) = env::var("ICEFLOE_CREDENTIALS") {
        // A robot with access control: log in as its owner.
        let text = fs::read_to_string(&path).unwrap_or_default();
        let (Some(user), Some(password)) = (credential(&text, "user"), credential(&text, "password")) else {
            eprintln!("battery_screen: {path}: no user or password in it");
            process::exit(2);
        };
        config.insert_json5("transport/auth/usrpwd/user", &serde_json::json!(user).to_string()).unwrap();
        config.insert_json5("transport/auth/usrpwd/password", &serde_json::json!(password).to_string()).unwrap();
    }
    let session = zenoh::open(config).wait().unwrap_or_else(|_| {
        eprintln!("battery_screen: cannot reach the robot's router at {connect}");
        process::exit(1);
    });

    // The newest reading: written on a Zenoh thread, read below.
    let latest: Arc<Mutex<Option<battery::BatteryReading>>> = Arc::default();
    let bad = Arc::new(AtomicUsize::new(0));
    let (latest_in, bad_in) = (latest.clone(), bad.clone());
    let battery_key = format!("{prefix}hw/battery");
    let _subscriber = session
        .declare_subscriber(&battery_key)
        .callback(move |sample| match battery::decode(&sample.payload().to_bytes()) {
            Ok(reading) => *latest_in.lock().unwrap() = Some(reading), // short: never block here
            Err(_) => {
                bad_in.fetch_add(1, Ordering::Relaxed);
            }
        })
        .wait()
        .unwrap();
    let _token = session.liveliness().declare_token(format!("{prefix}alive/{service}")).wait().unwrap(); // "I am running"
    let publisher = session.declare_publisher(format!("{prefix}oled/text")).encoding(Encoding::APPLICATION_JSON)
        .wait().unwrap();

    let running = Arc::new(AtomicBool::new(true));
    let stop = running.clone();
    ctrlc::set_handler(move || stop.store(false, Ordering::SeqCst)).unwrap();
    println!("battery_screen: showing {battery_key} on the screen of {robot}");
    let mut reported_bad = 0;
    while running.load(Ordering::SeqCst) {
        let bad_now = bad.load(Ordering::Relaxed);
        if bad_now != reported_bad {
            // One line per second at most, naming the key.
            eprintln!("battery_screen: {battery_key}: {bad_now} samples that are not a BatteryReading");
            reported_bad = bad_now;
        }
        let reading = latest.lock().unwrap().clone();
        if let Some(reading) = reading {
            let json = battery::text_json(&reading);
            publisher.put(json.clone()).wait().unwrap();
            println!("{json}");
        }
        std::thread::sleep(Duration::from_secs(1));
    }
    // The token, the subscriber and the session close as they go out of scope.
    println!("battery_screen: stopped");
}
