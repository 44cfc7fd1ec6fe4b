#!/usr/bin/env bash
# A service in a shell script: the robot's battery on its screen, every second, with curl and the
# web API's HTTP bridge to the bus (docs/webapi.md). No Zenoh and no Python: what any language
# that speaks HTTP can do. In a robot config, `icefloe up` runs it like its own services:
#
#   [programs.battery_screen]
#   command = ["bash", "curl_service.sh"]      # relative to the config file's folder
#
# and tells it where the bridge is (ICEFLOE_WEBAPI) and, on a robot with access control, where
# the robot's credentials file is (ICEFLOE_CREDENTIALS): writing needs the owner's password.
set -uo pipefail
bridge="${ICEFLOE_WEBAPI:-http://127.0.0.1:8080}"

# curl's options for the owner's user and password, read from the credentials file and handed to
# curl as a config file on a pipe: a password on a command line would show in `ps` to everyone.
login() {
    [ -n "${ICEFLOE_CREDENTIALS:-}" ] || return 0
    local user password
    user=$(sed -n 's/^user *= *"\(.*\)"$/\1/p' "$ICEFLOE_CREDENTIALS")
    password=$(sed -n 's/^password *= *"\(.*\)"$/\1/p' "$ICEFLOE_CREDENTIALS")
    printf 'user = "%s:%s"\n' "$user" "$password"
}

echo "showing the battery on the screen, through $bridge"
while true; do
    # GET: the latest hw/battery sample; ?_raw gives the message alone, {"stamp":..,"voltage":..,..}
    if battery=$(curl -sf --max-time 5 "$bridge/bus/hw/battery?_raw"); then
        volts=$(printf '%s' "$battery" | sed -n 's/.*"voltage":\([-0-9.e]*\).*/\1/p')
        text=$(printf 'battery %.2f V' "$volts")
        # PUT: the JSON body is checked against the key's message (OledText) before it is published.
        if answer=$(printf '{"text": "%s"}' "$text" | curl -sS --max-time 5 -X PUT --data-binary @- \
                -H 'Content-Type: application/json' -K <(login) -w ' %{http_code}' "$bridge/bus/oled/text") \
                && [ "${answer##* }" = 200 ]; then
            echo "$text"
        else
            echo "oled/text refused: $answer"
        fi
    else
        echo "no battery reading from $bridge yet"
    fi
    sleep 1
done
