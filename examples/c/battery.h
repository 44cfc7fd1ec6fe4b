/* The messages this service reads and writes, without Zenoh: decoding hw/battery
 * (MessagePack, as the robot publishes it) and writing oled/text (JSON, as the robot
 * accepts it). Kept apart from main so it can be tested on a machine without zenoh-c. */
#ifndef BATTERY_H
#define BATTERY_H

#include <stddef.h>
#include <stdint.h>

/* hw/battery, schemas/json/BatteryReading.json */
struct battery {
    int64_t stamp;  /* ns since the Unix epoch: more than a double holds exactly */
    double voltage; /* V */
    double current; /* A */
};

/* Decode a BatteryReading: a MessagePack map keyed by field name. Returns 0, or -1 if
 * the bytes are not such a map (a field missing or of the wrong type). */
int battery_decode(const uint8_t *data, size_t size, struct battery *out);

/* The OledText message showing it, as JSON: {"text": "battery 7.40 V"}. Returns the
 * length written (as snprintf does). */
int battery_text_json(const struct battery *reading, char *out, size_t size);

#endif
