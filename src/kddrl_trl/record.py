"""Record naturalistic traffic: ``python -m kddrl_trl.record [+scenario=congested] [duration_s=900] ...``.

Runs :func:`kddrl_trl.data.synthetic.record_env_traffic`: the recorder of the env node's simulator
(:func:`kddrl_trl.data.synthetic.traffic_recorder`: our SUMO highway's
:func:`~kddrl_trl.data.sumo_to_highd.record_traffic`, or with ``env=highwayenv`` HighwayEnv's own traffic,
:mod:`kddrl_trl.data.highwayenv_to_highd`) on the highway config composed from
``conf/record.yaml`` (``env: highway`` + optional ``+scenario=...`` + ``env.*`` overrides), writes one HighD
recording per road into ``out_dir`` (``XX_tracks.csv``, ``XX_tracksMeta.csv``, ``XX_recordingMeta.csv``
and ``XX_driverParams.csv``, each atomically) and prints the vehicle count, the share of lane changers and
the driver-type counts beside the paper's figures. The top-level ``num_roads`` sets the number of
recordings; ``env.num_roads`` (the RL env's batch size) is ignored.
"""

from __future__ import annotations  # noqa: I001  (kddrl_trl.conf must be imported before hydra)


from kddrl_trl import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra; first)

import hydra
from omegaconf import DictConfig, OmegaConf

from kddrl_trl.data.synthetic import record_env_traffic


@hydra.main(version_base="1.3", config_path="conf", config_name="record")
def main(cfg: DictConfig) -> dict:
    return record_env_traffic(
        OmegaConf.to_object(cfg.env),
        cfg.out_dir,
        int(cfg.seed),
        float(cfg.duration_s),
        int(cfg.num_roads),
        bool(cfg.progress),
    )


if __name__ == "__main__":
    main()
