import numpy as np

from teamslam.msckf.consensus.messages import MapIdsMessage
from teamslam.runtime import wire

team = wire.team_id("lissajous-demo")
ids = np.array([3, 4, 7, 130])
moved = np.array([True, False, True, True])
message = MapIdsMessage(sender=0, receiver=1, step=42, ids=ids, moved=moved)
data = wire.encode(message, team)
assert data[:4] == b"TSLM" and data[4] == wire.FORMAT_VERSION
# the header, one byte per id (6 = zigzag(3), then the differences 1, 3, 123), one byte of flags
assert len(data) == 36 + 4 + 1
back = wire.decode(data, team, n_robots=3)
assert back.step == 42 and list(back.ids) == [3, 4, 7, 130] and list(back.moved) == list(moved)
