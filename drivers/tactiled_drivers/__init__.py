"""Frame-source drivers, one module per URL scheme, behind :class:`tactiled.sources.FrameSource`.

``serial``, ``sim``, ``replay``, and the devices labs own (docs/howto/drivers.md: ``lines``,
``flexitac``, ``robotiq``, ``xela``, ``paxini``, each a pure :class:`tactiled.sources.Framer`
and a driver); ``plumbing`` holds what they share and no URL names.  This package imports none
of them: :func:`tactiled.sources.open_source` imports a driver only when its scheme is used, so
a missing optional library breaks only that driver.
"""
