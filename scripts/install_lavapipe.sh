#!/usr/bin/env sh
# Installs Mesa's software Vulkan driver (lavapipe) and the Vulkan loader, so that a build
# with `--features wgpu` runs on any CPU: tests/gpu_backends.rs compares the wgpu backend
# with the CPU backends when a Vulkan device is present (README, *GPU backends*).
# Run it as root (e.g. with sudo); it needs the distribution's package mirror.
set -eu
if command -v apt-get >/dev/null 2>&1; then
    apt-get update
    apt-get install -y --no-install-recommends mesa-vulkan-drivers libvulkan1
elif command -v dnf >/dev/null 2>&1; then
    dnf install -y mesa-vulkan-drivers vulkan-loader
elif command -v pacman >/dev/null 2>&1; then
    pacman -Sy --noconfirm vulkan-swrast vulkan-icd-loader
else
    echo "install Mesa's lavapipe (mesa-vulkan-drivers) and the Vulkan loader with your package manager" >&2
    exit 1
fi
if ls /usr/share/vulkan/icd.d/lvp* >/dev/null 2>&1; then
    echo "lavapipe installed: $(ls /usr/share/vulkan/icd.d/lvp*)"
else
    echo "no lavapipe driver in /usr/share/vulkan/icd.d after the install" >&2
    exit 1
fi
