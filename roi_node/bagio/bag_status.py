"""BagStatus: what became of an output bag, the one set of values the writer, replay, the recorder,
validation and the fleet share.

The writer stores the status in metadata.yaml's custom_data (`roi_node.status`),
so the values are the strings existing bags already carry; validation reads it
back to tell a complete bag from one cut short. The keys live here, below the
writer and the reader, so every bag module can take them.
"""

from __future__ import annotations

from enum import StrEnum

STATUS_KEY = "roi_node.status"
RECORDED_BY_KEY = "roi_node.recorded_by"  # custom_data of a `record` bag: the roi_node version that recorded it


class BagStatus(StrEnum):
    COMPLETE = "complete"  # finalized after all its input was written
    # Ctrl-C stopped the run: a replay finalizes what it had under `<out>.interrupted`; the fleet keeps nothing of the bag
    INTERRUPTED = "interrupted"
    FAILED = "failed"  # finalized with what it had after a write or processing failure
    RECORDING = "recording"  # an in-place recording still open (or never finished: `roi-node recover`)
    RECOVERED = "recovered"  # rebuilt by `roi-node recover` from the whole messages of an unfinished one
    DISCARDED = "discarded"  # the writer removed what it had written: no bag is left
    SKIPPED = "skipped"  # the fleet found the output complete from an earlier run, verified by its manifest, not redone


RECORDING = BagStatus.RECORDING
