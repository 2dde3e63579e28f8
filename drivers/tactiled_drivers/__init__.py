"""Frame-source drivers, one module per URL scheme, behind :class:`tactiled.sources.FrameSource`.

- ``serial.SerialSource``: ``serial:///dev/ttyACM0?baud=...`` (pyserial);
- ``sim.SimSource``: ``sim://?seed=...&scene=...`` (scene simulator -> encoder -> bytes);
- ``replay.ReplaySource``: ``replay://FILE?speed=1.0&loop=0``;
- the devices labs own (docs/howto/drivers.md), each a pure framer (a
  :class:`tactiled.sources.Framer`) and a driver: ``lines.LinesSource`` (``lines://``),
  ``flexitac.FlexiTacSource`` (``flexitac://``), ``robotiq.RobotiqSource`` (``robotiq://``),
  ``xela.XelaSource`` (``xela://``), ``paxini.PaxiniSource`` (``paxini://``);
- ``plumbing``: what the drivers share and no URL names (the serial port reader and its
  guard thread, the framers' counters and clock, asyncio helpers).

This package imports none of them: :func:`tactiled.sources.open_source` imports a driver's
module only when its scheme is used, so a missing optional library breaks only that driver.
"""
