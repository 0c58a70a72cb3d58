#include "counters.h"

dyno_counters_t g_counters;
