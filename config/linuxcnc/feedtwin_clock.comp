component feedtwin_clock "Index and CLOCK_MONOTONIC start time of each period of the thread it runs in";
description """Add it first to the servo thread. The sampler records both pins each period:
gaps in tick count lost samples, and time_s minus a reader's receive time is the delivery
latency. In the uspace build rtapi_get_time() reads CLOCK_MONOTONIC, the clock of Python's
time.monotonic(), so the two compare on one host.""";
pin out s32 tick "periods run since the component was loaded, counting from 0";
pin out float time_s "rtapi_get_time() when this period's functions started [s]";
variable rtapi_s64 count = 0;
function _;
license "GPL";
;;
FUNCTION(_) {
    time_s = rtapi_get_time() * 1e-9;
    tick = (hal_s32_t)count;
    count++;
}
