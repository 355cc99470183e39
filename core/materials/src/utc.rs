//! UTC timestamps (`YYYY-MM-DDTHH:MM:SSZ`, proleptic Gregorian) for reports and
//! recovery journals, without a calendar dependency.

use std::time::SystemTime;

/// The timestamp of `seconds` since 1970-01-01T00:00:00Z.
pub fn from_unix(seconds: u64) -> String {
    let (days, rem) = ((seconds / 86_400) as i64, seconds % 86_400);
    let (y, m, d) = civil_from_days(days);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// The timestamp of a time (times before 1970 read as 1970-01-01).
pub fn timestamp(when: SystemTime) -> String {
    from_unix(
        when.duration_since(SystemTime::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0),
    )
}

/// The Gregorian date of a day count since 1970-01-01, by eras of 400 years (146097
/// days), with years starting in March so the leap day ends the year.
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn timestamps_match_known_dates() {
        let at = |s: u64| timestamp(SystemTime::UNIX_EPOCH + Duration::from_secs(s));
        assert_eq!(at(0), "1970-01-01T00:00:00Z");
        // 2000-02-29 12:34:56 (a leap day of a century leap year) = 951827696 (date -d).
        assert_eq!(at(951_827_696), "2000-02-29T12:34:56Z");
        // 2100-03-01 (2100 is not a leap year) = 4107542400.
        assert_eq!(at(4_107_542_400), "2100-03-01T00:00:00Z");
        assert_eq!(at(1_767_225_599), "2025-12-31T23:59:59Z");
        assert_eq!(from_unix(1_798_761_600), "2027-01-01T00:00:00Z");
    }
}
