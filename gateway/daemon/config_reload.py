"""The SIGHUP reload of `Gateway` (gateway/daemon/supervisor.py): the config read again,
checked all or nothing (`preflight.refuse_reload`, the sensor model's lag), applied to the
wires, the board side and the port; a refused reload keeps the running config and says why.

A mixin: `Gateway` inherits these methods; they use its state (cfg, wires, pipeline,
board, notifier, counters) as their own.
"""
from __future__ import annotations

import logging

from gateway.config import Config
from gateway.daemon.preflight import refuse_reload
from gateway.daemon.settings import calibration_from, estimator_settings_from, model_terms_from, serial_settings_from
from gateway.errors import ConfigError, DeviceError

log = logging.getLogger("adxlgw")


class ConfigReload:
    """`reload()` and its helpers, for `Gateway`."""

    async def _reload_logged(self) -> None:
        """A reload from a signal: nobody awaits it, so a failure is said here."""
        try:
            await self.reload()
        except Exception as err:  # a bug or a device that would not start: say it, keep running
            log.error("reload failed: %s", err)
            self.notifier.ready()

    def _model_terms_for_reload(self, new: Config):
        """The new config's sensor-model corrections (read again: the file may have been
        rewritten under the same name); ConfigError when its filter terms would change
        the estimator's sensor lag, which is set when the estimator is built."""
        terms = model_terms_from(new)
        if estimator_settings_from(new).sensor_lag_s != self._sensor_lag_s:
            raise ConfigError(f"{new.source}: calibration.model: {new.calibration.model or '(none)'}: its filter "
                              "terms change the estimator's sensor lag, set when the estimator is built: restart "
                              "the gateway to apply it")
        return terms

    async def reload(self) -> None:
        if self._reload is None:
            log.warning("SIGHUP: no config file to reload")
            return
        await self._board_side_built.wait()  # a SIGHUP while starting: once the start is done
        self.notifier.reloading()
        self._drain(self.clock())  # the bytes received so far, under the config they came with
        try:
            new = self._reload()
            refuse_reload(self.cfg, new)  # all or nothing: a changed wire that cannot work refuses it
            model_terms = self._model_terms_for_reload(new)
        except ConfigError as err:
            self.counters.config_reload_errors += 1
            log.error("reload refused, keeping the running config: %s", err)
            self.notifier.ready()
            return
        old = self.cfg
        try:
            await self.wires.apply(old, new)
        except DeviceError as err:
            self.counters.config_reload_errors += 1
            log.error("reload refused, keeping the running config: %s", err)
            self.notifier.ready()
            return
        self.cfg = new
        self.counters.config_reloads += 1
        self._reloaded_at = self.clock()
        # the reload is news on every wire (CONFIG_RELOADED) now, not at the next sample: a
        # wire whose settings did not change is not touched by apply, and its image would
        # show the values from before the reload until the board speaks again
        self._publish(self._reloaded_at)
        logging.getLogger().setLevel(new.service.log_level.upper())
        self.pipeline.set_calibration(calibration_from(new), new.calibration.axis)
        self.pipeline.set_model_terms(model_terms)
        # the travel bounds the published σ, and the saved position read at the next start
        self.pipeline.set_travel(tuple(new.estimator.travel_m))
        self.state_store.travel_m = tuple(new.estimator.travel_m)
        port_changed = (old.serial.port != new.serial.port
                        or serial_settings_from(old, "port") != serial_settings_from(new, "port"))
        # while the port is still being opened, the opener takes the new settings itself
        if port_changed and self.ready:
            log.info("reload: reopening the board port")
            self.board.reopen()
        log.info("config reloaded from %s", new.source)
        self.notifier.ready()
