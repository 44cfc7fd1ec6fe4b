/* battery.c on its own: MessagePack on stdin, the JSON to send on stdout (exit 1 if it
 * does not decode). tests/test_other_languages.py feeds it what icefloe publishes. */
#include <stdio.h>

#include "battery.h"

int main(void) {
    uint8_t data[4096];
    size_t size = fread(data, 1, sizeof data, stdin);
    struct battery reading;
    if (battery_decode(data, size, &reading) != 0) {
        fprintf(stderr, "not a BatteryReading\n");
        return 1;
    }
    char json[128];
    battery_text_json(&reading, json, sizeof json);
    printf("%lld %s\n", (long long)reading.stamp, json);
    return 0;
}
