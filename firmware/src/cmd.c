/* cmd_check() is inline in cmd.h (it runs in the TWI ISR). This unit only anchors
 * the header in builds that list every module. */
#include "cmd.h"
