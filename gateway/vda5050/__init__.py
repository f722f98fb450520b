"""VDA 5050 master control over MQTT: the broker connection (:mod:`.broker`) and the driver
that runs :class:`protocol.vda5050.master.VehicleMaster` for configured vehicles."""
