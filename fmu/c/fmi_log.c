/*
 * dobkit FMUs: message text helpers shared by the FMI 2 and FMI 3 layers (see fmi_log.h).
 */
#include "fmi_log.h"

void fmi_escape_percent(const char *message, char *out, size_t size)
{
    size_t i, j = 0;
    if (size == 0) return;
    /* j + 2 < size leaves room for a doubled '%' and the terminator */
    for (i = 0; message[i] && j + 2 < size; i++) {
        if (message[i] == '%') out[j++] = '%';
        out[j++] = message[i];
    }
    out[j] = '\0';
}
