"""vrsim as the rate modules and the AgOpenGPS/AgIO side of SK21's AgOpenGPS Rate Controller (AOG_RC).

* `services.aog.pgn`: the PGNs' byte layouts (the module's side: what it reads and what it sends), pure;
* `services.aog.firmware`: the rate module's firmware (its PID, flow sensor, relays, the 4 s rule) on
  vrsim's plant, a class stepped every 50 ms, pure;
* `services.aog.field`: the scenario's SUMO drive as AgIO sends it, and the run's outputs at its end;
* `services.aog.service`: the UDP service (`vrsim serve aog-rc`);
* `services.aog.app_client`: the Rate Controller app's side, written from its C# sources on its own
  (it imports nothing of the above), for tests and `vrsim aog`.

docs/aog_rc.md says which file and commit of AOG_RC each layout was read from.
"""
