"""`python -m hsio.monitor RUN_DIR`: `hsio monitor RUN_DIR` as `hsio run --monitor` starts it
beside a run: below the run's priority (nice 10; on a busy machine the loop gets the processor
first) and deaf to the terminal's Ctrl-C, which is the run's to obey (the run then ends the page)."""

import os
import signal

from hsio.commands.monitor import monitor

if __name__ == "__main__":
    os.nice(10)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    monitor(prog_name="hsio monitor")
