// dyno Nano firmware. Everything lives in src/ (setup() and loop() in src/main.cpp);
// the Arduino IDE compiles src/ with this sketch, PlatformIO and the Makefile build
// src/ directly. This file only names the sketch.
#include "src/config.h"
