/* Shared by the native unit tests (make -C firmware test): the check counter. */
#ifndef DYNO_TEST_NATIVE_H
#define DYNO_TEST_NATIVE_H
#include <stdio.h>

extern int failures, checks;
#define CHECK(cond, ...) do { checks++; if (!(cond)) { failures++; \
    printf("FAIL %s:%d: ", __FILE__, __LINE__); printf(__VA_ARGS__); printf("\n"); } } while (0)

/* A command with its CRC-16 (test_proto.c): its length */
#include <stdint.h>
uint8_t mk_cmd(uint8_t *out, uint8_t op, const uint8_t *args, uint8_t nargs);

void test_proto_basics(void);
void test_proto_lossless(void);
void test_supervisor_machine(void);
void test_supervisor_proto(void);

#endif
