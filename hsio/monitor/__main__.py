"""`python -m hsio.monitor RUN_DIR`: `hsio monitor RUN_DIR` as `hsio run --monitor` starts it
beside a run: below the run's priority (nice 10; on a busy machine the loop gets the processor
first), deaf to the terminal's Ctrl-C, which is the run's to obey (the run then ends the page),
and ending with the run however the run ends (:func:`hsio.monitor.server.end_with_parent`)."""

import os
import signal
import stat

from hsio.commands.monitor import monitor
from hsio.monitor.server import end_with_parent

if __name__ == "__main__":
    os.nice(10)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if stat.S_ISFIFO(os.fstat(0).st_mode):  # started by a parent that holds the other end
        end_with_parent()
    monitor(prog_name="hsio monitor")
