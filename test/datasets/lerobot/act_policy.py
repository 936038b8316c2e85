"""A LeRobot ACT policy built from an exported dataset's features, with random weights, saved as a pretrained folder.

Nothing is downloaded: the ResNet backbone starts from random weights
(pretrained_backbone_weights None) and the normalisation stats are the
dataset's own. The inputs are the dataset's images and observation.state;
the output is its action.
"""

from __future__ import annotations

from pathlib import Path

import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.datasets.utils import dataset_to_policy_features
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors

STATE_KEY = "observation.state"


def save_random_act(dataset: Path, out: Path, *, chunk_size: int, seed: int = 0) -> ACTConfig:
    meta = LeRobotDatasetMetadata("roi_node/act_closed_loop", root=dataset)
    features = dataset_to_policy_features(meta.features)
    inputs = {k: f for k, f in features.items() if f.type is FeatureType.VISUAL or k == STATE_KEY}
    outputs = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config = ACTConfig(input_features=inputs, output_features=outputs, chunk_size=chunk_size, n_action_steps=chunk_size,
                       pretrained_backbone_weights=None, device="cpu")
    torch.manual_seed(seed)
    policy = ACTPolicy(config)
    preprocess, postprocess = make_pre_post_processors(config, dataset_stats=meta.stats)
    policy.save_pretrained(out)
    preprocess.save_pretrained(out)
    postprocess.save_pretrained(out)
    return config
