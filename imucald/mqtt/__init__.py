"""The MQTT bridge (``imucald mqtt``): topics and payloads in :mod:`.topics` (pure),
the process in :mod:`.bridge` (needs paho-mqtt, the ``mqtt`` extra)."""
