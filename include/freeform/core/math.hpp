#pragma once
// Small fixed-size vector maths usable in FREEFORM_HD kernels. Eigen serves the host
// side (images, linear algebra); kernels use this POD so they compile for the device
// without Eigen's CUDA configuration.
#include <cmath>

#include "hd.hpp"

namespace freeform {

template <class T>
struct Vec3T {
    T x{}, y{}, z{};

    FREEFORM_HD constexpr T operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    template <class U>
    FREEFORM_HD constexpr explicit operator Vec3T<U>() const {
        return {static_cast<U>(x), static_cast<U>(y), static_cast<U>(z)};
    }
};

using Vec3 = Vec3T<float>;
using Vec3d = Vec3T<double>;

template <class T>
struct Vec2T {
    T x{}, y{};
};
using Vec2 = Vec2T<float>;
using Vec2d = Vec2T<double>;

template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> operator+(Vec3T<T> a, Vec3T<T> b) {
    return {a.x + b.x, a.y + b.y, a.z + b.z};
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> operator-(Vec3T<T> a, Vec3T<T> b) {
    return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> operator-(Vec3T<T> a) {
    return {-a.x, -a.y, -a.z};
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> operator*(T s, Vec3T<T> a) {
    return {s * a.x, s * a.y, s * a.z};
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> operator*(Vec3T<T> a, T s) {
    return {s * a.x, s * a.y, s * a.z};
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> operator/(Vec3T<T> a, T s) {
    return {a.x / s, a.y / s, a.z / s};
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr bool operator==(Vec3T<T> a, Vec3T<T> b) {
    return a.x == b.x && a.y == b.y && a.z == b.z;
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr T dot(Vec3T<T> a, Vec3T<T> b) {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> cross(Vec3T<T> a, Vec3T<T> b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
template <class T>
FREEFORM_HD inline T length(Vec3T<T> a) {
    return std::sqrt(dot(a, a));
}
template <class T>
FREEFORM_HD inline Vec3T<T> normalize(Vec3T<T> a) {
    return a * (T(1) / length(a));
}

// Mirror reflection of direction d about unit normal n (either orientation).
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE constexpr Vec3T<T> reflect(Vec3T<T> d, Vec3T<T> n) {
    return d - (T(2) * dot(d, n)) * n;
}

// Snell refraction of unit direction d at unit normal n, going from index eta_from into
// eta_to. n may face either side. Returns false on total internal reflection.
template <class T>
FREEFORM_HD inline bool refract(Vec3T<T> d, Vec3T<T> n, T eta_from, T eta_to, Vec3T<T>& out) {
    T cos_i = -dot(d, n);
    if (cos_i < T(0)) {  // make n face the incoming ray
        n = -n;
        cos_i = -cos_i;
    }
    const T eta = eta_from / eta_to;
    const T sin2_t = eta * eta * (T(1) - cos_i * cos_i);
    if (sin2_t > T(1)) return false;
    const T cos_t = std::sqrt(T(1) - sin2_t);
    out = eta * d + (eta * cos_i - cos_t) * n;
    return true;
}

// Unpolarised Fresnel transmittance of a smooth interface for light meeting it at
// cos_i (cosine to the normal, in [0, 1]) going from index eta_from into eta_to: the
// mean of the s and p power transmittances, 1 - (r_s^2 + r_p^2) / 2. Zero beyond the
// critical angle. At normal incidence 1 - ((n1 - n2) / (n1 + n2))^2 (0.96 for 1 -> 1.5).
template <class T>
FREEFORM_HD inline T fresnel_transmittance(T cos_i, T eta_from, T eta_to) {
    cos_i = std::fmin(std::fabs(cos_i), T(1));
    const T eta = eta_from / eta_to;
    const T sin2_t = eta * eta * (T(1) - cos_i * cos_i);
    if (sin2_t >= T(1)) return T(0);
    const T cos_t = std::sqrt(T(1) - sin2_t);
    const T rs = (eta_from * cos_i - eta_to * cos_t) / (eta_from * cos_i + eta_to * cos_t);
    const T rp = (eta_from * cos_t - eta_to * cos_i) / (eta_from * cos_t + eta_to * cos_i);
    return T(1) - T(0.5) * (rs * rs + rp * rp);
}

inline constexpr double pi = 3.14159265358979323846;

constexpr double degrees_to_radians(double deg) { return deg * (pi / 180.0); }

}  // namespace freeform
