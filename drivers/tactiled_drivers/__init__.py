"""Frame-source drivers behind one interface, :class:`tactiled.sources.FrameSource`.

- ``serial_source.SerialSource``: ``serial:///dev/ttyACM0?baud=...`` (pyserial);
- ``sim.SimSource``: ``sim://?seed=...&scene=...`` (scene simulator -> encoder -> bytes);
- ``replay_source.ReplaySource``: ``replay://FILE?speed=1.0&loop=0``;
- the devices labs own (docs/howto/drivers.md), each a pure framer (``feed(bytes) -> frames``) and
  a driver: ``lines.LinesSource`` (``lines://``), ``flexitac.FlexiTacSource``
  (``flexitac://``), ``robotiq.RobotiqSource`` (``robotiq://``), ``xela.XelaSource``
  (``xela://``); ``framing`` holds what their framers share.

This package imports none of them: :func:`tactiled.sources.open_source` imports a driver's
module only when its scheme is used, so a missing optional library breaks only that driver.
"""
