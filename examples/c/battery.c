#include "battery.h"

#include <msgpack.h>
#include <stdio.h>
#include <string.h>

/* A number of the map: MessagePack may carry a float as an integer (7 instead of 7.0). */
static int number(const msgpack_object *value, double *out) {
    switch (value->type) {
        case MSGPACK_OBJECT_FLOAT32:
        case MSGPACK_OBJECT_FLOAT64: *out = value->via.f64; return 0;
        case MSGPACK_OBJECT_POSITIVE_INTEGER: *out = (double)value->via.u64; return 0;
        case MSGPACK_OBJECT_NEGATIVE_INTEGER: *out = (double)value->via.i64; return 0;
        default: return -1;
    }
}

static int is_key(const msgpack_object *key, const char *name) {
    return key->type == MSGPACK_OBJECT_STR && key->via.str.size == strlen(name) &&
           memcmp(key->via.str.ptr, name, key->via.str.size) == 0;
}

int battery_decode(const uint8_t *data, size_t size, struct battery *out) {
    msgpack_unpacked message;
    msgpack_unpacked_init(&message);
    int found = 0, ok = 0;
    if (msgpack_unpack_next(&message, (const char *)data, size, NULL) == MSGPACK_UNPACK_SUCCESS &&
        message.data.type == MSGPACK_OBJECT_MAP) {
        ok = 1;
        const msgpack_object_map *map = &message.data.via.map;
        for (uint32_t i = 0; i < map->size && ok; i++) {
            const msgpack_object *key = &map->ptr[i].key, *value = &map->ptr[i].val;
            if (is_key(key, "stamp") && value->type == MSGPACK_OBJECT_POSITIVE_INTEGER) {
                out->stamp = (int64_t)value->via.u64;
                found |= 1;
            } else if (is_key(key, "voltage")) {
                ok = number(value, &out->voltage) == 0;
                found |= 2;
            } else if (is_key(key, "current")) {
                ok = number(value, &out->current) == 0;
                found |= 4;
            }
        }
    }
    msgpack_unpacked_destroy(&message);
    return ok && found == 7 ? 0 : -1;
}

int battery_text_json(const struct battery *reading, char *out, size_t size) {
    return snprintf(out, size, "{\"text\": \"battery %.2f V\"}", reading->voltage);
}
