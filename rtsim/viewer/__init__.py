"""`rtsim view`: the driving simulator in the browser (a local web server joined to the service over Zenoh)."""
