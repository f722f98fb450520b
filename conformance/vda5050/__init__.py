"""``fleetgate conformance vda5050``: a VDA 5050 vehicle checked by a master control."""
