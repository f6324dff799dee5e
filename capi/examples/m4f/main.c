/* Cortex-M4F C example of the stjpdacf C API, bare metal under QEMU mps2-an386 (the machine of
 * the Rust firmware, bench/firmware): the frames of the firmware's `typical` scenario in the SPI
 * wire format (embedded with .incbin), decoded with stjpdacf_decode_frame, tracked with
 * stjpdacf_step (stjpdacf_small_step with -DSTJPDACF_EXAMPLE_SMALL, stjpdacf_rank5_step with
 * -DSTJPDACF_EXAMPLE_RANK5), every filtered and smoothed lane printed exactly as the Rust firmware's
 * `lanes_typical` binary prints it (`cargo xtask capi` compares the two), then the stack
 * high-water mark. No C library: semihosting by hand, the tracker in a static buffer.
 *
 *   arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16 -O2 \
 *     -ffreestanding -nostdlib -Icapi/include -DFRAMES_FILE='"bench/firmware/scenarios/typical.stjf"' \
 *     -T capi/examples/m4f/link.ld capi/examples/m4f/main.c \
 *     target/thumbv7em-none-eabihf/release/libstjpdacf_capi.a -lgcc -Wl,--gc-sections -o m4f.elf
 *   qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none \
 *     -semihosting-config enable=on,target=native -kernel m4f.elf */
#include <stddef.h>
#include <stdint.h>

#include "stjpdacf.h"

/* With -DSTJPDACF_EXAMPLE_SMALL the small model (stjpdacf_small_*), with
 * -DSTJPDACF_EXAMPLE_RANK5 the rank-5 model (stjpdacf_rank5_*); `cargo xtask capi` builds all
 * three and compares each with the Rust firmware built for the same model. */
#if defined(STJPDACF_EXAMPLE_SMALL)
#define TRACKER stjpdacf_small_tracker
#define TRACKER_SIZE STJPDACF_SMALL_TRACKER_SIZE
#define TRACKER_INIT stjpdacf_small_init
#define TRACKER_STEP stjpdacf_small_step
#define TRACKER_SMOOTHED stjpdacf_small_smoothed
#elif defined(STJPDACF_EXAMPLE_RANK5)
#define TRACKER stjpdacf_rank5_tracker
#define TRACKER_SIZE STJPDACF_RANK5_TRACKER_SIZE
#define TRACKER_INIT stjpdacf_rank5_init
#define TRACKER_STEP stjpdacf_rank5_step
#define TRACKER_SMOOTHED stjpdacf_rank5_smoothed
#else
#define TRACKER stjpdacf_tracker
#define TRACKER_SIZE STJPDACF_TRACKER_SIZE
#define TRACKER_INIT stjpdacf_init
#define TRACKER_STEP stjpdacf_step
#define TRACKER_SMOOTHED stjpdacf_smoothed
#endif

#ifndef FRAMES_FILE
#error "define FRAMES_FILE as the quoted path of a .stjf file"
#endif

/* The frames, back to back in the wire format. */
__asm__(".section .rodata.frames,\"a\"\n"
        ".balign 4\n"
        ".global frames_start\n"
        "frames_start:\n"
        ".incbin \"" FRAMES_FILE "\"\n"
        ".global frames_end\n"
        "frames_end:\n"
        ".previous\n");
extern const uint8_t frames_start[], frames_end[];

/* ---- semihosting (ARM: bkpt 0xAB, operation in r0, argument in r1) ---- */
#define SYS_OPEN 0x01
#define SYS_WRITE 0x05
#define SYS_EXIT 0x18
#define ADP_STOPPED_APPLICATION_EXIT 0x20026
#define ADP_STOPPED_RUN_TIME_ERROR 0x20023

static int semihost(int op, const void *arg) {
    register int r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static void __attribute__((noreturn)) exit_qemu(int ok) {
    semihost(SYS_EXIT, (const void *)(uintptr_t)(ok ? ADP_STOPPED_APPLICATION_EXIT
                                                    : ADP_STOPPED_RUN_TIME_ERROR));
    for (;;) {
    }
}

/* A line buffer, written out with one SYS_WRITE per line. */
static char line[640];
static size_t len;

static void put(const char *s) {
    while (*s && len + 1 < sizeof line) line[len++] = *s++;
}

static void put_u(uint32_t v) {
    char d[11];
    int n = 0;
    do {
        d[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    while (n) {
        char c[2] = {d[--n], 0};
        put(c);
    }
}

static void put_i(int32_t v) {
    if (v < 0) {
        put("-");
        put_u((uint32_t)(-(v + 1)) + 1u);
    } else {
        put_u((uint32_t)v);
    }
}

static void put_hex(float f) {
    union {
        float f;
        uint32_t u;
    } b = {f};
    char h[9];
    for (int i = 0; i < 8; i++) h[i] = "0123456789abcdef"[(b.u >> (28 - 4 * i)) & 0xf];
    h[8] = 0;
    put(h);
}

/* The host's stdout (":tt" opened for writing), as cortex-m-semihosting's hprintln does. */
static int stdout_handle = -1;

static void flush(void) {
    if (stdout_handle < 0) {
        const uintptr_t open_args[3] = {(uintptr_t)":tt", 4 /* "w" */, 3};
        stdout_handle = semihost(SYS_OPEN, open_args);
    }
    const uintptr_t write_args[3] = {(uintptr_t)stdout_handle, (uintptr_t)line, len};
    semihost(SYS_WRITE, write_args);
    len = 0;
}

/* ---- the tracker ---- */
static _Alignas(STJPDACF_TRACKER_ALIGN) unsigned char memory[TRACKER_SIZE];
static float points[2 * STJPDACF_MAX_POINTS];
static stjpdacf_lane lanes[STJPDACF_MAX_LANES];

static void print_lane(const char *tag, uint32_t k, const stjpdacf_lane *l) {
    put("LANE ");
    put(tag);
    const uint32_t ints[] = {k, l->id, l->slot, l->misses, l->age, l->hits};
    for (size_t i = 0; i < sizeof ints / sizeof ints[0]; i++) {
        put(" ");
        put_u(ints[i]);
    }
    const float ext[] = {l->u_first, l->u_last, l->existence};
    for (size_t i = 0; i < 3; i++) {
        put(" ");
        put_hex(ext[i]);
    }
    for (size_t i = 0; i < STJPDACF_INDEX_POINTS; i++) {
        put(" ");
        put_hex(l->z[i]);
    }
    for (size_t i = 0; i < STJPDACF_INDEX_POINTS; i++) {
        put(" ");
        put_hex(l->var[i]);
    }
    put("\n");
    flush();
}

static void fail(const char *what, int32_t status) {
    put("ERROR ");
    put(what);
    put(" status=");
    put_i(status);
    put("\n");
    flush();
    exit_qemu(0 /* failure */);
}

#define PAINT 0xCCCCCCCCu
extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _stack_end, _stack_start;

/* Bytes of stack ever used: painted words overwritten, scanning up from the stack's far end. */
static uint32_t stack_used(void) {
    const volatile uint32_t *p = &_stack_end;
    while (p < &_stack_start && *p == PAINT) p++;
    return (uint32_t)((uintptr_t)&_stack_start - (uintptr_t)p);
}

static int run(void) {
    struct TRACKER *t = NULL;
    stjpdacf_status st = TRACKER_INIT(memory, sizeof memory, &t);
    if (st != STJPDACF_OK) fail("init", st);
    const uint8_t *f = frames_start;
    uint32_t k = 0;
    while (f < frames_end) {
        stjpdacf_frame_info info;
        st = stjpdacf_decode_frame(f, (size_t)(frames_end - f), points, STJPDACF_MAX_POINTS,
                                   &info);
        if (st != STJPDACF_OK) fail("stjpdacf_decode_frame", st);
        stjpdacf_report rep;
        st = TRACKER_STEP(t, info.time_us, points, info.count, lanes, STJPDACF_MAX_LANES, &rep);
        if (st < 0) fail("step", st);
        for (uint32_t i = 0; i < rep.filtered_lanes; i++) print_lane("F", k, &lanes[i]);
        size_t n = 0;
        st = TRACKER_SMOOTHED(t, lanes, STJPDACF_MAX_LANES, &n);
        if (st != STJPDACF_OK) fail("smoothed", st);
        for (size_t i = 0; i < n; i++) print_lane("S", k, &lanes[i]);
        f += info.len;
        k++;
    }
    put("FRAMES ");
    put_u(k);
    put("\nSTACK used=");
    put_u(stack_used());
    put(" size=");
    put_u((uint32_t)((uintptr_t)&_stack_start - (uintptr_t)&_stack_end));
    put("\nDONE ok\n");
    flush();
    return 1;
}

/* ---- start-up ---- */
static void __attribute__((noinline)) start(void) {
    uint32_t *s = &_sidata, *d = &_sdata;
    while (d < &_edata) *d++ = *s++;
    for (d = &_sbss; d < &_ebss; d++) *d = 0;
    /* Paint the stack below the current frame (with a margin). */
    uint32_t sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (volatile uint32_t *p = &_stack_end; (uintptr_t)p < sp - 256; p++) *p = PAINT;
    exit_qemu(run());
}

void __attribute__((noreturn)) reset_handler(void) {
    /* The FPU on (CPACR: CP10 and CP11 full access) before any floating-point instruction. */
    *(volatile uint32_t *)0xE000ED88 |= 0xFu << 20;
    __asm__ volatile("dsb\n isb" ::: "memory");
    start();
    for (;;) {
    }
}

static void fault_handler(void) {
    put("HARDFAULT\n");
    flush();
    exit_qemu(0);
}

__attribute__((section(".vectors"), used)) static const void *const vectors[16] = {
    &_stack_start, (const void *)reset_handler, (const void *)fault_handler,
    (const void *)fault_handler, (const void *)fault_handler, (const void *)fault_handler,
    (const void *)fault_handler,
};
