/*
 * dobkit FMUs: message text helpers shared by the FMI 2 and FMI 3 layers of the plant and the controller.
 */
#ifndef DOBKIT_FMI_LOG_H
#define DOBKIT_FMI_LOG_H

#include <stddef.h>

/* Size of an escaped log message, terminator included; longer messages are cut. */
#define FMI_LOG_SIZE 2100

/* Copy `message` into `out` (`size` bytes, always terminated, cut if too long), doubling every '%':
 * an FMI 2 logger reads its message as a printf format. */
void fmi_escape_percent(const char *message, char *out, size_t size);

#endif
