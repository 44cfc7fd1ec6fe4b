/* battery_screen: the robot's battery on its screen, once a second. A complete icefloe
 * service in C with zenoh-c 1.x: the same service as examples/curl_service.sh, over Zenoh.
 *
 *   subscribes  icefloe/<robot>/hw/battery   BatteryReading, MessagePack (battery.c)
 *   publishes   icefloe/<robot>/oled/text    OledText, JSON
 *   holds       icefloe/<robot>/alive/<service>, so `icefloe status` lists it
 *
 * Under `icefloe up` ([programs.battery_screen] in the robot config) it is told the robot,
 * its router and its credentials file in ICEFLOE_ROBOT, ICEFLOE_CONNECT and
 * ICEFLOE_CREDENTIALS (docs/own-services.md); run by hand, set them yourself. Ctrl-C
 * (SIGINT) or SIGTERM ends it cleanly. */
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "battery.h"
#include "zenoh.h"

static volatile sig_atomic_t running = 1;
static void on_signal(int signum) { (void)signum; running = 0; }

/* The newest reading: written on a Zenoh thread, read by main. */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static struct battery latest;
static int have_reading = 0;
static int bad_readings = 0;

static void on_battery(z_loaned_sample_t *sample, void *context) {
    (void)context;
    z_owned_slice_t bytes;
    z_bytes_to_slice(z_sample_payload(sample), &bytes);
    struct battery reading;
    int ok = battery_decode(z_slice_data(z_loan(bytes)), z_slice_len(z_loan(bytes)), &reading) == 0;
    z_drop(z_move(bytes));
    pthread_mutex_lock(&lock);  /* short: never block in a Zenoh callback */
    if (ok) {
        latest = reading;
        have_reading = 1;
    } else {
        bad_readings++;
    }
    pthread_mutex_unlock(&lock);
}

static const char *env_or(const char *name, const char *fallback) {
    const char *value = getenv(name);
    return value && *value ? value : fallback;
}

/* `key = "value"` from the robot's credentials file (a TOML file made by `icefloe credentials`). */
static int credential(const char *path, const char *key, char *out, size_t size) {
    FILE *file = fopen(path, "r");
    if (!file) return -1;
    char line[512], format[64];
    snprintf(format, sizeof format, "%s = \"%%%zu[^\"]\"", key, size - 1);
    int found = -1;
    while (found != 0 && fgets(line, sizeof line, file)) found = sscanf(line, format, out) == 1 ? 0 : -1;
    fclose(file);
    return found;
}

/* A config value as JSON: the string in quotes (endpoints, user and password have no quotes). */
static void insert_string(z_loaned_config_t *config, const char *key, const char *value) {
    char json[600];
    snprintf(json, sizeof json, "\"%s\"", value);
    zc_config_insert_json5(config, key, json);
}

int main(void) {
    const char *robot = env_or("ICEFLOE_ROBOT", "sim");
    const char *service = env_or("ICEFLOE_SERVICE", "battery_screen");
    const char *connect = env_or("ICEFLOE_CONNECT", "tcp/127.0.0.1:7447");
    const char *credentials = getenv("ICEFLOE_CREDENTIALS");

    /* A client of the robot's router, no multicast scouting: this robot, not any. */
    z_owned_config_t config;
    z_config_default(&config);
    zc_config_insert_json5(z_loan_mut(config), "mode", "\"client\"");
    zc_config_insert_json5(z_loan_mut(config), "scouting/multicast/enabled", "false");
    char endpoints[300];
    snprintf(endpoints, sizeof endpoints, "[\"%s\"]", connect);  /* one endpoint */
    zc_config_insert_json5(z_loan_mut(config), "connect/endpoints", endpoints);
    if (credentials) {  /* a robot with access control: log in as its owner */
        char user[128], password[256];
        if (credential(credentials, "user", user, sizeof user) || credential(credentials, "password", password,
                                                                                 sizeof password)) {
            fprintf(stderr, "battery_screen: %s: no user or password in it\n", credentials);
            return 2;
        }
        insert_string(z_loan_mut(config), "transport/auth/usrpwd/user", user);
        insert_string(z_loan_mut(config), "transport/auth/usrpwd/password", password);
    }
    z_owned_session_t session;
    if (z_open(&session, z_move(config), NULL) < 0) {
        fprintf(stderr, "battery_screen: cannot reach the robot's router at %s\n", connect);
        return 1;
    }

    char key[256];
    snprintf(key, sizeof key, "icefloe/%s/hw/battery", robot);
    z_view_keyexpr_t battery_key;
    z_view_keyexpr_from_str(&battery_key, key);
    z_owned_closure_sample_t callback;
    z_closure(&callback, on_battery, NULL, NULL);
    z_owned_subscriber_t subscriber;
    z_declare_subscriber(z_loan(session), &subscriber, z_loan(battery_key), z_move(callback), NULL);

    char alive[256];
    snprintf(alive, sizeof alive, "icefloe/%s/alive/%s", robot, service);
    z_view_keyexpr_t alive_key;
    z_view_keyexpr_from_str(&alive_key, alive);
    z_owned_liveliness_token_t token;  /* "I am running" */
    z_liveliness_declare_token(z_loan(session), &token, z_loan(alive_key), NULL);

    char text_key_str[256];
    snprintf(text_key_str, sizeof text_key_str, "icefloe/%s/oled/text", robot);
    z_view_keyexpr_t text_key;
    z_view_keyexpr_from_str(&text_key, text_key_str);

    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    printf("battery_screen: showing %s on the screen of %s\n", key, robot);
    fflush(stdout);
    int reported_bad = 0;
    while (running) {
        pthread_mutex_lock(&lock);
        struct battery reading = latest;
        int have = have_reading, bad = bad_readings;
        pthread_mutex_unlock(&lock);
        if (bad != reported_bad) {  /* one line per second at most, naming the key */
            fprintf(stderr, "battery_screen: %s: %d samples that are not a BatteryReading\n", key, bad);
            reported_bad = bad;
        }
        if (have) {
            char json[128];
            battery_text_json(&reading, json, sizeof json);
            z_put_options_t options;
            z_put_options_default(&options);
            z_owned_encoding_t encoding;
            z_encoding_from_str(&encoding, "application/json");
            options.encoding = z_move(encoding);
            z_owned_bytes_t payload;
            z_bytes_copy_from_str(&payload, json);
            z_put(z_loan(session), z_loan(text_key), z_move(payload), &options);
            printf("%s\n", json);
            fflush(stdout);
        }
        sleep(1);
    }

    z_drop(z_move(token));
    z_drop(z_move(subscriber));
    z_drop(z_move(session));
    printf("battery_screen: stopped\n");
    return 0;
}
