"""The plant: the lathe the regulation acts on, and what measures it. The PMC's dead time, the
feed servo, the cutting process and the feed drive's currents (settings :mod:`.settings`,
compiled :mod:`.lathe`, the friction both the plant and the estimator use :mod:`.feeddrive`);
the drive as a force sensor (:mod:`.drive`) and the DAQ's raw samples (:mod:`.daq`)."""
