"""Record and replay: a robot session in an MCAP file (https://mcap.dev), played back onto the bus.

* `writer.BagWriter`: bus samples -> an MCAP file (one channel per key, JSON Schema + JSON, so
  Foxglove and any JSON reader decode it with no plug-in; see `channels`).
* `reader.Bag`: the messages of a file (or a split recording) back, in order; truncated files
  up to their last whole chunk.
* `replay.replay`: a recording published onto the bus with its original timing and encodings.
* `export.to_csv`: one CSV per key, for homework that starts from a file.

The `icefloe record`, `replay`, `bag info` and `export` verbs (``icefloe/cli/record.py``) and
``icefloe viz FILE.mcap`` are thin layers over these. docs/record-replay.md is the guide.
"""

from .channels import ChannelPlan
from .reader import Bag, Entry
from .writer import BagWriter

__all__ = ["Bag", "BagWriter", "ChannelPlan", "Entry"]
