// The compiled simulation's test bench: the world's side of the icoBoard's pins, cycle by cycle.
//
// Built by icefloe/gateware/cxxsim.py together with the C++ that Yosys' CXXRTL backend
// makes of `IcoBoardCore` (top.cc, included below), into one shared library that Python
// loads with ctypes. Per cycle work stays here, in C++; Python calls once per SPI exchange
// and once per simulated millisecond:
//
//   ico_exchange   clock one SPI mode 0 exchange through the pins (as the Pi's controller)
//   ico_step       run N cycles: move the encoder phases towards their targets, and count
//                  how long each PWM pin was high (and with DIR set) -- what a motor averages
//   ico_read       those counts and the board's strobes since the last read
//
// Port names are CXXRTL's: p_ + the port name with '_' doubled.

#include <cstdint>
#include <cstring>

#include "top.cc"

namespace {

constexpr int MAX = 8;  // encoders and PWM outputs (icefloe.gateware.core.MAX_PERIPHERALS)

struct Stats {
    uint64_t cycles;            // cycles run since the last read
    uint64_t total_cycles;      // cycles run since the board was made
    uint64_t pwm_high[MAX];     // cycles each PWM pin was high
    uint64_t pwm_reverse[MAX];  // ... of them, with the DIR pin high
    uint32_t frames_valid;
    uint32_t frames_rejected;
    uint32_t trips;             // watchdog trips
    uint32_t pwm_periods;       // PWM periods begun (output 0)
    uint64_t last_valid_cycle;  // total_cycles at the last valid frame (kept across reads)
    uint64_t last_high_cycle;   // total_cycles when a PWM pin was last high (kept across reads)
    uint32_t running;           // levels now
    uint32_t watchdog;
    uint32_t pwm;
    uint32_t dir;
};

struct Board {
    cxxrtl_design::p_top top;
    Stats stats{};
    int64_t position[MAX]{};    // encoder steps shown on the pins
    int64_t target[MAX]{};      // steps the wheel has turned
    uint32_t encoders = 0;
    uint32_t actuators = 0;
    uint32_t a_bits = 0, b_bits = 0;

    void cycle() {
        top.p_clk.set<bool>(false);
        top.step();
        top.p_clk.set<bool>(true);
        top.step();
        const uint32_t pwm = top.p_pwm.get<uint32_t>();
        const uint32_t dir = top.p_dir.get<uint32_t>();
        for (uint32_t i = 0; i < actuators; i++) {
            if (pwm >> i & 1) {
                stats.pwm_high[i]++;
                if (dir >> i & 1) stats.pwm_reverse[i]++;
            }
        }
        if (pwm) stats.last_high_cycle = stats.total_cycles;
        if (top.p_frame__valid.get<bool>()) stats.last_valid_cycle = stats.total_cycles;
        stats.frames_valid += top.p_frame__valid.get<bool>();
        stats.frames_rejected += top.p_frame__rejected.get<bool>();
        stats.trips += top.p_tripped.get<bool>();
        stats.pwm_periods += top.p_pwm__period__start.get<bool>();
        stats.cycles++;
        stats.total_cycles++;
    }

    // One quadrature step of encoder i towards its target; A leads B going forward.
    void move(uint32_t i) {
        static const uint8_t a_of[4] = {0, 1, 1, 0}, b_of[4] = {0, 0, 1, 1};
        position[i] += target[i] > position[i] ? 1 : -1;
        const uint32_t phase = static_cast<uint32_t>(position[i] & 3);
        a_bits = (a_bits & ~(1u << i)) | (uint32_t(a_of[phase]) << i);
        b_bits = (b_bits & ~(1u << i)) | (uint32_t(b_of[phase]) << i);
        top.p_enc__a.set<uint32_t>(a_bits);
        top.p_enc__b.set<uint32_t>(b_bits);
    }
};

}  // namespace

extern "C" {

void *ico_new(uint32_t encoders, uint32_t actuators) {
    Board *board = new Board;
    board->encoders = encoders;
    board->actuators = actuators;
    board->top.p_cs__n.set<bool>(true);
    board->top.p_rst.set<bool>(true);
    board->cycle();
    board->top.p_rst.set<bool>(false);
    return board;
}

void ico_free(void *handle) { delete static_cast<Board *>(handle); }

// Encoder targets in steps (the world's unbounded counts); ico_step moves the pins there.
void ico_encoders(void *handle, const int64_t *targets) {
    Board *board = static_cast<Board *>(handle);
    std::memcpy(board->target, targets, sizeof(int64_t) * board->encoders);
}

// Run `cycles` cycles, spreading the encoder steps still to go evenly over them.
void ico_step(void *handle, uint64_t cycles) {
    Board *board = static_cast<Board *>(handle);
    uint64_t pending[MAX], done[MAX]{};
    for (uint32_t i = 0; i < board->encoders; i++) {
        const int64_t d = board->target[i] - board->position[i];
        pending[i] = static_cast<uint64_t>(d < 0 ? -d : d);
    }
    for (uint64_t c = 0; c < cycles; c++) {
        for (uint32_t i = 0; i < board->encoders; i++) {
            // step k of n happens at cycle k * cycles / (n + 1): evenly apart, none at the edges
            if (done[i] < pending[i] && c * (pending[i] + 1) >= (done[i] + 1) * cycles) {
                board->move(i);
                done[i]++;
            }
        }
        board->cycle();
    }
}

// One SPI mode 0 exchange of n bytes, SCK high and low for `half` cycles each; CS goes low
// `lead` cycles before the first rising edge and stays high `gap` cycles after. CIPO is
// sampled `setup` cycles before each rising edge (pad delays and the controller's setup time).
// Returns the cycle (of total_cycles) at which CS fell.
uint64_t ico_exchange(void *handle, const uint8_t *tx, uint8_t *rx, uint32_t n, uint32_t half,
                      uint32_t lead, uint32_t gap, uint32_t setup) {
    Board *board = static_cast<Board *>(handle);
    auto &top = board->top;
    const uint64_t fell = board->stats.total_cycles;
    top.p_cs__n.set<bool>(false);
    for (uint32_t k = 0; k < n; k++) {
        uint8_t got = 0;
        for (int bit = 7; bit >= 0; bit--) {
            top.p_copi.set<bool>(tx[k] >> bit & 1);
            const uint32_t wait = (k == 0 && bit == 7) ? lead : half;
            for (uint32_t c = 0; c < wait; c++) {
                if (c == wait - setup) got = static_cast<uint8_t>(got << 1 | top.p_cipo.get<bool>());
                board->cycle();
            }
            if (setup == 0) got = static_cast<uint8_t>(got << 1 | top.p_cipo.get<bool>());
            top.p_sck.set<bool>(true);
            for (uint32_t c = 0; c < half; c++) board->cycle();
            top.p_sck.set<bool>(false);
        }
        rx[k] = got;
    }
    for (uint32_t c = 0; c < half; c++) board->cycle();
    top.p_cs__n.set<bool>(true);
    for (uint32_t c = 0; c < gap; c++) board->cycle();
    return fell;
}

// Run until PWM output `channel` shows `level`, at most `limit` cycles; returns the cycles run.
uint64_t ico_until_pwm(void *handle, uint32_t channel, uint32_t level, uint64_t limit) {
    Board *board = static_cast<Board *>(handle);
    uint64_t c = 0;
    while (c < limit && (board->top.p_pwm.get<uint32_t>() >> channel & 1) != level) {
        board->cycle();
        c++;
    }
    return c;
}

// Cycles run since the board was made.
uint64_t ico_cycles(void *handle) { return static_cast<Board *>(handle)->stats.total_cycles; }

// The counts since the last read, and the levels now; then start counting afresh.
void ico_read(void *handle, Stats *out) {
    Board *board = static_cast<Board *>(handle);
    board->stats.running = board->top.p_running.get<bool>();
    board->stats.watchdog = board->top.p_watchdog.get<bool>();
    board->stats.pwm = board->top.p_pwm.get<uint32_t>();
    board->stats.dir = board->top.p_dir.get<uint32_t>();
    *out = board->stats;
    const Stats kept = board->stats;
    board->stats = Stats{};
    board->stats.total_cycles = kept.total_cycles;
    board->stats.last_valid_cycle = kept.last_valid_cycle;
    board->stats.last_high_cycle = kept.last_high_cycle;
}

}  // extern "C"
